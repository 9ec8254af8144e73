/* USART0 at 9600 baud: see uart.h. Works on the ATmega328P (Uno, Nano) and the ATmega2560/1280 (Mega). */
#include "uart.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#define BAUD ILLUMINATOR_BAUD
#include <util/setbaud.h>

#if defined(USART0_RX_vect)
#define ILLUMINATOR_UART_RX_VECT USART0_RX_vect
#elif defined(USART_RX_vect)
#define ILLUMINATOR_UART_RX_VECT USART_RX_vect
#else
#error "this MCU has no USART0 receive interrupt that the illuminator firmware knows"
#endif

/* A power of two so the indices wrap with a mask. Commands are 20-odd bytes and the host waits for each
 * reply, so this only has to cover one line arriving while the LED is being written or a reply sent. */
#define RX_BUFFER_SIZE 64u

static volatile uint8_t rx_buffer[RX_BUFFER_SIZE];
static volatile uint8_t rx_head;
static volatile uint8_t rx_tail;

ISR(ILLUMINATOR_UART_RX_VECT)
{
    uint8_t byte = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1u) & (RX_BUFFER_SIZE - 1u));
    if (next != rx_tail) {
        rx_buffer[rx_head] = byte;
        rx_head = next;
    }
}

void illuminator_uart_init(void)
{
    UBRR0H = UBRRH_VALUE;
    UBRR0L = UBRRL_VALUE;
#if USE_2X
    UCSR0A = _BV(U2X0);
#else
    UCSR0A = 0;
#endif
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

int16_t illuminator_uart_read(void)
{
    if (rx_head == rx_tail) {
        return -1;
    }
    uint8_t byte = rx_buffer[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1u) & (RX_BUFFER_SIZE - 1u));
    return byte;
}

static void write_byte(uint8_t byte)
{
    loop_until_bit_is_set(UCSR0A, UDRE0);
    UDR0 = byte;
}

void illuminator_uart_write_line(const char *text)
{
    while (*text != '\0') {
        write_byte((uint8_t)*text++);
    }
    write_byte('\r');
    write_byte('\n');
}
