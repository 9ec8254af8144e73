/* The line parser of the illuminator's serial protocol: see protocol.h. Plain C99, no hardware. */
#include "protocol.h"

#include <stddef.h>

static const char reply_done[] = ILLUMINATOR_REPLY_DONE;
static const char reply_id[] = ILLUMINATOR_REPLY_ID;
static const char reply_error[] = ILLUMINATOR_REPLY_ERROR;

void illuminator_parser_init(illuminator_parser_t *parser)
{
    parser->length = 0;
    parser->discard = 0;
    parser->line[0] = '\0';
}

illuminator_command_t illuminator_parser_feed(illuminator_parser_t *parser, char byte, uint8_t rgb[3])
{
    if (byte == '\n' || byte == '\r') {
        illuminator_command_t command;
        if (parser->discard) {
            command = ILLUMINATOR_ERROR;
        } else if (parser->length == 0) {
            command = ILLUMINATOR_NONE;
        } else {
            parser->line[parser->length] = '\0';
            command = illuminator_parse_line(parser->line, rgb);
        }
        illuminator_parser_init(parser);
        return command;
    }
    if (parser->discard) {
        return ILLUMINATOR_NONE;
    }
    /* A NUL would end the C string early and hide what follows it, so every non-text byte spoils the line. */
    if (parser->length >= ILLUMINATOR_LINE_MAX || !((byte >= ' ' && byte <= '~') || byte == '\t')) {
        parser->discard = 1;
        return ILLUMINATOR_NONE;
    }
    parser->line[parser->length++] = byte;
    return ILLUMINATOR_NONE;
}

static const char *skip_blanks(const char *text)
{
    while (*text == ' ' || *text == '\t') {
        ++text;
    }
    return text;
}

static int is_end_of_word(char c)
{
    return c == '\0' || c == ' ' || c == '\t';
}

/* Returns the text after the word, or NULL when the text does not start with it as a whole word. */
static const char *match_word(const char *text, const char *word)
{
    while (*word != '\0') {
        if (*text++ != *word++) {
            return NULL;
        }
    }
    return is_end_of_word(*text) ? text : NULL;
}

/* Parses an unsigned decimal 0-255 (leading zeros allowed); NULL for no digits, a value above 255, or a
 * number running into another character ("12a"). Stops accumulating past 255, so it cannot overflow. */
static const char *parse_channel(const char *text, uint8_t *value)
{
    uint16_t number = 0;
    const char *start = text;
    while (*text >= '0' && *text <= '9') {
        number = (uint16_t)(number * 10u + (uint16_t)(*text - '0'));
        if (number > 255u) {
            return NULL;
        }
        ++text;
    }
    if (text == start || !is_end_of_word(*text)) {
        return NULL;
    }
    *value = (uint8_t)number;
    return text;
}

illuminator_command_t illuminator_parse_line(const char *line, uint8_t rgb[3])
{
    const char *text = skip_blanks(line);
    const char *rest = match_word(text, "id?");
    if (rest != NULL) {
        return *skip_blanks(rest) == '\0' ? ILLUMINATOR_IDENTIFY : ILLUMINATOR_ERROR;
    }
    rest = match_word(text, "set_rgb");
    if (rest == NULL) {
        return ILLUMINATOR_ERROR;
    }
    uint8_t values[3];
    for (uint8_t i = 0; i < 3; ++i) {
        rest = parse_channel(skip_blanks(rest), &values[i]);
        if (rest == NULL) {
            return ILLUMINATOR_ERROR;
        }
    }
    if (*skip_blanks(rest) != '\0') {
        return ILLUMINATOR_ERROR;
    }
    for (uint8_t i = 0; i < 3; ++i) {
        rgb[i] = values[i];
    }
    return ILLUMINATOR_SET_RGB;
}

const char *illuminator_reply(illuminator_command_t command)
{
    switch (command) {
    case ILLUMINATOR_SET_RGB:
        return reply_done;
    case ILLUMINATOR_IDENTIFY:
        return reply_id;
    case ILLUMINATOR_ERROR:
        return reply_error;
    case ILLUMINATOR_NONE:
    default:
        return NULL;
    }
}
