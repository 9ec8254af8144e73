/* The entry point for building with avr-gcc and the Makefile. The Arduino IDE compiles this file too, but
 * its core brings its own main() that calls setup() and loop() from neopixel_illuminator.ino. */
#ifndef ARDUINO

#include "illuminator.h"

int main(void)
{
    illuminator_setup();
    for (;;) {
        illuminator_poll();
    }
}

#endif
