/*
 * picamcal's calibration illuminator: one NeoPixel (WS2812, GRB, 800 kHz) on pin 6 behind a paper diffuser,
 * set over the USB serial port at 9600 baud (FORMATS.md section 7, the paper's Arduino):
 *
 *   set_rgb R G B   (0-255 each)  ->  done.
 *   id?                           ->  picamcal-illuminator 1
 *   anything else                 ->  Error: command is set_rgb <int> <int> <int>
 *
 * The code is plain avr-libc in the .c files beside this sketch, so it needs no library (not even
 * Adafruit_NeoPixel) and also builds without the IDE: see README.md. For a 16 MHz Uno, Nano or Mega.
 */
#include "illuminator.h"

void setup()
{
    illuminator_setup();
}

void loop()
{
    illuminator_poll();
}
