/* One WS2812 ("NeoPixel") chain on Arduino pin 6, bit-banged at 800 kHz with a cycle-counted loop. */
#ifndef PICAMCAL_ILLUMINATOR_WS2812_H
#define PICAMCAL_ILLUMINATOR_WS2812_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Make the data pin an output, drive it low and wait for the LEDs to latch. */
void illuminator_ws2812_init(void);

/* Send count bytes (GRB, GRB, ... for a chain), most significant bit first, then wait for the latch. */
void illuminator_ws2812_send(const uint8_t *bytes, uint8_t count);

#ifdef __cplusplus
}
#endif

#endif
