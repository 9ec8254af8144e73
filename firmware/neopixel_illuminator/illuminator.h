/* The illuminator firmware: the serial protocol (protocol.h) driving one NeoPixel (ws2812.h). */
#ifndef PICAMCAL_ILLUMINATOR_H
#define PICAMCAL_ILLUMINATOR_H

#ifdef __cplusplus
extern "C" {
#endif

/* Switch the LED off, start the UART and enable interrupts. */
void illuminator_setup(void);

/* Handle at most one received byte; replies and sets the LED at the end of each line. */
void illuminator_poll(void);

#ifdef __cplusplus
}
#endif

#endif
