/* The illuminator firmware's main logic: see illuminator.h. */
#include "illuminator.h"

#include <avr/interrupt.h>
#include <stdint.h>

#include "protocol.h"
#include "uart.h"
#include "ws2812.h"

static illuminator_parser_t parser;

static void show_rgb(const uint8_t rgb[3])
{
    const uint8_t grb[3] = {rgb[1], rgb[0], rgb[2]};
    illuminator_ws2812_send(grb, sizeof grb);
}

void illuminator_setup(void)
{
    /* The host opening the port resets the board, and a WS2812 keeps its colour across that: start dark. */
    static const uint8_t off[3] = {0, 0, 0};
    illuminator_ws2812_init();
    show_rgb(off);
    illuminator_parser_init(&parser);
    illuminator_uart_init();
    sei();
}

void illuminator_poll(void)
{
    int16_t received = illuminator_uart_read();
    if (received < 0) {
        return;
    }
    uint8_t rgb[3];
    illuminator_command_t command = illuminator_parser_feed(&parser, (char)received, rgb);
    if (command == ILLUMINATOR_SET_RGB) {
        show_rgb(rgb); /* before "done.": the reply means the light is set */
    }
    const char *reply = illuminator_reply(command);
    if (reply != 0) {
        illuminator_uart_write_line(reply);
    }
}
