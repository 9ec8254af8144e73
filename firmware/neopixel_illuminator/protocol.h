/*
 * The illuminator's serial protocol (FORMATS.md section 7, the paper's Arduino), free of any hardware so
 * that the host's C compiler can test it too.
 *
 *   set_rgb R G B   (0-255 each)  ->  "done."
 *   id?                           ->  "picamcal-illuminator 1"
 *   anything else                 ->  "Error: command is set_rgb <int> <int> <int>"
 *
 * Lines end with '\n' or '\r' (so "\r\n" works too; the empty line it leaves is ignored). A line longer than
 * ILLUMINATOR_LINE_MAX characters, or one holding a byte that is not printable ASCII or a tab, is an error.
 */
#ifndef PICAMCAL_ILLUMINATOR_PROTOCOL_H
#define PICAMCAL_ILLUMINATOR_PROTOCOL_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* "set_rgb 255 255 255" is 19 characters; the rest is room for extra blanks and leading zeros. */
#define ILLUMINATOR_LINE_MAX 40

#define ILLUMINATOR_REPLY_DONE "done."
#define ILLUMINATOR_REPLY_ID "picamcal-illuminator 1"
#define ILLUMINATOR_REPLY_ERROR "Error: command is set_rgb <int> <int> <int>"

typedef enum {
    ILLUMINATOR_NONE = 0, /* no complete line yet, or an empty one: nothing to do, no reply */
    ILLUMINATOR_SET_RGB = 1,
    ILLUMINATOR_IDENTIFY = 2,
    ILLUMINATOR_ERROR = 3
} illuminator_command_t;

typedef struct {
    char line[ILLUMINATOR_LINE_MAX + 1];
    uint8_t length;
    uint8_t discard; /* the line is already known bad (too long, or a stray byte): skip to its end */
} illuminator_parser_t;

void illuminator_parser_init(illuminator_parser_t *parser);

/* Feed one received byte; at the end of a line, returns the command (rgb filled in for ILLUMINATOR_SET_RGB). */
illuminator_command_t illuminator_parser_feed(illuminator_parser_t *parser, char byte, uint8_t rgb[3]);

/* Parse one complete line without its terminator; rgb is written only for ILLUMINATOR_SET_RGB. */
illuminator_command_t illuminator_parse_line(const char *line, uint8_t rgb[3]);

/* The reply line (without terminator) the device sends for a command; NULL for ILLUMINATOR_NONE. */
const char *illuminator_reply(illuminator_command_t command);

#ifdef __cplusplus
}
#endif

#endif
