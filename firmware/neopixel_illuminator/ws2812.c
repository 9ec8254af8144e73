/*
 * WS2812 bit-banging for a 16 MHz AVR (one cycle = 62.5 ns): see ws2812.h.
 *
 * Every bit starts with a rising edge and lasts 20 cycles (1.25 us, 800 kHz). A 0 falls after 6 cycles
 * (375 ns), a 1 after 13 cycles (812.5 ns); the WS2812B datasheet asks for T0H = 400 +- 150 ns and
 * T1H = 800 +- 150 ns, the older WS2812 for 350 and 700 +- 150 ns: both fit. The low time after the last bit of
 * a byte is 5 cycles longer while the next byte is loaded, well inside what the LEDs accept (they latch only
 * after tens of microseconds low). Interrupts are off while the bits go out, so the UART interrupt (or the
 * Arduino core's timer) cannot stretch a pulse; a 3-byte frame keeps them off for 30 us, far less than the
 * 1 ms a byte takes at 9600 baud, so no received byte is lost.
 */
#include "ws2812.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/delay.h>

#if F_CPU != 16000000
#error "the WS2812 timing is counted in cycles of a 16 MHz clock"
#endif

/* Arduino digital pin 6: PD6 on the Uno and Nano, PH3 on the Mega. */
#if defined(__AVR_ATmega328P__) || defined(__AVR_ATmega328__) || defined(__AVR_ATmega168__) || \
    defined(__AVR_ATmega168P__) || defined(__AVR_ATmega168PA__)
#define WS2812_DDR DDRD
#define WS2812_PORT PORTD
#define WS2812_BIT PD6
#elif defined(__AVR_ATmega2560__) || defined(__AVR_ATmega1280__)
#define WS2812_DDR DDRH
#define WS2812_PORT PORTH
#define WS2812_BIT PH3
#else
#error "unknown MCU: add the port and bit of Arduino pin 6 for it"
#endif

/* The WS2812B latches after more than 280 us low (the older WS2812 after 50 us). */
#define WS2812_LATCH_US 300

void illuminator_ws2812_init(void)
{
    WS2812_PORT &= (uint8_t)~_BV(WS2812_BIT);
    WS2812_DDR |= _BV(WS2812_BIT);
    _delay_us(WS2812_LATCH_US);
}

void illuminator_ws2812_send(const uint8_t *bytes, uint8_t count)
{
    if (count == 0) {
        return;
    }
    uint8_t sreg = SREG;
    cli();
    /* Read with interrupts off, so the other pins of the port keep their levels. PORTH of the Mega is out
     * of reach of OUT/SBI, so the pin is written through a pointer: ST takes 2 cycles on both chips. */
    volatile uint8_t *port = &WS2812_PORT;
    uint8_t high = (uint8_t)(*port | _BV(WS2812_BIT));
    uint8_t low = (uint8_t)(*port & ~_BV(WS2812_BIT));
    uint8_t byte;
    uint8_t bits;
    uint8_t next;
    /* Cycle counts from the rising edge of each bit. The level stored at c6 is chosen by SBRC + MOV, which
     * take 2 cycles whether the bit is 0 or 1 (a skip over a 1-word instruction costs 2), so both kinds of bit
     * last exactly 20 cycles; a conditional skip over the store itself would make a 1 one cycle shorter. */
    __asm__ __volatile__(
        "1:  ld   %[byte], %a[data]+ \n\t" /* next byte (2), then 8 bits (1)          */
        "    ldi  %[bits], 8         \n\t"
        "2:  st   %a[port], %[high]  \n\t" /* c0-1   rising edge                     */
        "    mov  %[next], %[low]    \n\t" /* c2                                      */
        "    sbrc %[byte], 7         \n\t" /* c3     a 0 skips the next move (c3-4)  */
        "    mov  %[next], %[high]   \n\t" /* c4                                      */
        "    nop                     \n\t" /* c5                                      */
        "    st   %a[port], %[next]  \n\t" /* c6-7   a 0 falls here: T0H = 6 cycles  */
        "    lsl  %[byte]            \n\t" /* c8                                      */
        "    nop                     \n\t" /* c9                                      */
        "    nop                     \n\t" /* c10                                     */
        "    nop                     \n\t" /* c11                                     */
        "    dec  %[bits]            \n\t" /* c12    sets Z for the brne below        */
        "    st   %a[port], %[low]   \n\t" /* c13-14 a 1 falls here: T1H = 13 cycles */
        "    nop                     \n\t" /* c15                                     */
        "    nop                     \n\t" /* c16                                     */
        "    nop                     \n\t" /* c17                                     */
        "    brne 2b                 \n\t" /* c18-19 the next bit rises at c20        */
        "    dec  %[count]           \n\t" /* after the 8th bit: c19                  */
        "    brne 1b                 \n\t" /* c20-21, ld c22-23, ldi c24, rise at c25 */
        : [byte] "=&r"(byte), [bits] "=&d"(bits), [next] "=&r"(next), [data] "+z"(bytes), [count] "+r"(count)
        : [port] "x"(port), [high] "r"(high), [low] "r"(low)
        : "memory");
    SREG = sreg;
    _delay_us(WS2812_LATCH_US);
}
