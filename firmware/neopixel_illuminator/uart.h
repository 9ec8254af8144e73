/* USART0 at 9600 baud, 8N1, register level (no Arduino core): received bytes are buffered by an interrupt. */
#ifndef PICAMCAL_ILLUMINATOR_UART_H
#define PICAMCAL_ILLUMINATOR_UART_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define ILLUMINATOR_BAUD 9600

void illuminator_uart_init(void);

/* The next received byte, or -1 when none is waiting. */
int16_t illuminator_uart_read(void);

/* Send a text and "\r\n" (as the Arduino's Serial.println), waiting until each byte is handed to the USART. */
void illuminator_uart_write_line(const char *text);

#ifdef __cplusplus
}
#endif

#endif
