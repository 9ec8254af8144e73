/*
 * Run the illuminator firmware in simavr, for the tests: its USART0 is bridged to a pseudo-terminal that a host
 * program (picamcal's SerialIlluminator, pyserial, ...) opens like the Arduino's port, and the WS2812 data pin
 * (Arduino pin 6) is decoded from its simulated edges.
 *
 *   illuminator-sim MCU FIRMWARE.elf [SECONDS]
 *
 * Prints on stdout (other lines are simavr's own chatter):
 *   pty /dev/pts/N                      once the firmware runs and the pty is ready
 *   frame bytes=G,R,B,... bits=24 t0h=MIN,MAX t1h=MIN,MAX period=MIN,MAX
 *                                       each WS2812 frame, after its latch; times in CPU cycles (16 MHz)
 * and ends when its standard input is closed, or after SECONDS (default 120) of wall time.
 *
 * Simulated time is held to wall time (never more than a few milliseconds ahead), so the UART runs at a real
 * 9600 baud and an idle firmware does not keep a host core busy.
 *
 * simavr's own command line cannot bridge a UART, and the uart_pty part of libsimavrparts links every instance
 * to the same /tmp/simavr-uart0, so tests running side by side would collide: hence this small harness.
 */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_ioport.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>

#define CPU_HZ 16000000UL
#define MAX_FRAME_BYTES 64
/* A bit whose high time exceeds this many cycles (0.6 us, the middle of T0H and T1H) is a 1. */
#define ONE_THRESHOLD_CYCLES 10
/* 50 us low latches the frame (the WS2812's reset time). */
#define LATCH_CYCLES (CPU_HZ / 20000)
/* UCSR0A is at data address 0xC0 with UDRE0 as bit 5 on the ATmega328P and the ATmega2560 alike. */
#define UCSR0A_ADDRESS 0xC0
#define UDRE0_MASK 0x20

typedef struct {
    avr_t *avr;
    int master;
    avr_irq_t *uart_input;
    int uart_full;
    avr_cycle_count_t cycles_per_byte;
    avr_cycle_count_t last_byte_in;
    avr_cycle_count_t last_byte_out;
    unsigned char pending[256];
    ssize_t pending_length;
    ssize_t pending_done;
} bridge_t;

typedef struct {
    int level;
    avr_cycle_count_t rise;
    avr_cycle_count_t fall;
    unsigned bits;
    unsigned char bytes[MAX_FRAME_BYTES];
    avr_cycle_count_t t0h[2];
    avr_cycle_count_t t1h[2];
    avr_cycle_count_t period[2];
} decoder_t;

static void widen(avr_cycle_count_t range[2], avr_cycle_count_t value)
{
    if (range[0] == 0 || value < range[0]) {
        range[0] = value;
    }
    if (value > range[1]) {
        range[1] = value;
    }
}

static void uart_output_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    bridge_t *bridge = param;
    unsigned char byte = (unsigned char)value;
    bridge->last_byte_out = bridge->avr->cycle;
    /* The host may have closed its side for a moment: a lost byte is what a real unplugged board does. */
    if (write(bridge->master, &byte, 1) < 0 && errno != EAGAIN && errno != EIO) {
        perror("illuminator-sim: write to pty");
    }
}

static void uart_xoff_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    ((bridge_t *)param)->uart_full = value != 0;
}

static void uart_xon_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    ((bridge_t *)param)->uart_full = 0;
}

/* Set by main: the decoder needs the simulator's cycle counter at each edge. */
static avr_t *simulated;

static void data_pin_hook(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    decoder_t *decoder = param;
    int level = value != 0;
    avr_cycle_count_t now = simulated->cycle;
    if (level == decoder->level) {
        return;
    }
    decoder->level = level;
    if (level) {
        if (decoder->bits > 0) {
            widen(decoder->period, now - decoder->rise);
        }
        decoder->rise = now;
        return;
    }
    decoder->fall = now;
    avr_cycle_count_t high = now - decoder->rise;
    int one = high > ONE_THRESHOLD_CYCLES;
    widen(one ? decoder->t1h : decoder->t0h, high);
    if (decoder->bits < 8u * MAX_FRAME_BYTES) {
        unsigned index = decoder->bits / 8u;
        decoder->bytes[index] = (unsigned char)((decoder->bytes[index] << 1) | one);
    }
    decoder->bits++;
}

static void report_frame_if_latched(decoder_t *decoder)
{
    if (decoder->bits == 0 || decoder->level || simulated->cycle - decoder->fall < LATCH_CYCLES) {
        return;
    }
    printf("frame bytes=");
    unsigned count = decoder->bits / 8u < MAX_FRAME_BYTES ? decoder->bits / 8u : MAX_FRAME_BYTES;
    for (unsigned i = 0; i < count; ++i) {
        printf(i ? ",%u" : "%u", decoder->bytes[i]);
    }
    printf(" bits=%u t0h=%llu,%llu t1h=%llu,%llu period=%llu,%llu\n", decoder->bits,
           (unsigned long long)decoder->t0h[0], (unsigned long long)decoder->t0h[1],
           (unsigned long long)decoder->t1h[0], (unsigned long long)decoder->t1h[1],
           (unsigned long long)decoder->period[0], (unsigned long long)decoder->period[1]);
    fflush(stdout);
    memset(decoder, 0, sizeof *decoder);
}

/*
 * simavr 1.6 clears UDRE0 when the firmware writes UCSR0B while the flag is set, which the Arduino core's init()
 * does (UCSR0B = 0) before setup(): a sketch polling UDRE0 would then wait forever. A real USART keeps UDRE0 set
 * whenever its transmit buffer is empty, so set it again once no byte has gone out for a byte's time.
 */
static void keep_udre_while_idle(bridge_t *bridge)
{
    if (bridge->avr->cycle - bridge->last_byte_out > 2 * bridge->cycles_per_byte) {
        bridge->avr->data[UCSR0A_ADDRESS] |= UDRE0_MASK;
    }
}

/* Hand the firmware's UART the host's bytes no faster than the line rate, as a real port would. */
static void feed_uart(bridge_t *bridge)
{
    if (bridge->pending_done == bridge->pending_length) {
        ssize_t got = read(bridge->master, bridge->pending, sizeof bridge->pending);
        if (got <= 0) {
            return;
        }
        bridge->pending_length = got;
        bridge->pending_done = 0;
    }
    if (bridge->uart_full || bridge->avr->cycle - bridge->last_byte_in < bridge->cycles_per_byte) {
        return;
    }
    bridge->last_byte_in = bridge->avr->cycle;
    avr_raise_irq(bridge->uart_input, bridge->pending[bridge->pending_done++]);
}

static double seconds_since(const struct timespec *start)
{
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (double)(now.tv_sec - start->tv_sec) + 1e-9 * (double)(now.tv_nsec - start->tv_nsec);
}

static int stdin_closed(void)
{
    struct pollfd input = {.fd = STDIN_FILENO, .events = POLLIN};
    if (poll(&input, 1, 0) <= 0) {
        return 0;
    }
    char scratch[64];
    return read(STDIN_FILENO, scratch, sizeof scratch) <= 0;
}

static void pin_of(const char *mcu, char *port, int *bit)
{
    if (strcmp(mcu, "atmega2560") == 0 || strcmp(mcu, "atmega1280") == 0) {
        *port = 'H'; /* Arduino Mega pin 6 = PH3 */
        *bit = 3;
    } else {
        *port = 'D'; /* Uno and Nano pin 6 = PD6 */
        *bit = 6;
    }
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: %s MCU FIRMWARE.elf [SECONDS]\n", argv[0]);
        return 2;
    }
    const char *mcu = argv[1];
    double limit = argc > 3 ? atof(argv[3]) : 120.0;

    elf_firmware_t firmware;
    memset(&firmware, 0, sizeof firmware);
    if (elf_read_firmware(argv[2], &firmware) != 0) {
        fprintf(stderr, "illuminator-sim: cannot read %s\n", argv[2]);
        return 1;
    }
    snprintf(firmware.mmcu, sizeof firmware.mmcu, "%s", mcu);
    firmware.frequency = CPU_HZ;
    avr_t *avr = avr_make_mcu_by_name(mcu);
    if (avr == NULL) {
        fprintf(stderr, "illuminator-sim: simavr knows no %s\n", mcu);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &firmware);
    simulated = avr;

    static bridge_t bridge;
    bridge.avr = avr;
    char slave_name[128];
    int slave;
    if (openpty(&bridge.master, &slave, slave_name, NULL, NULL) != 0) {
        perror("illuminator-sim: openpty");
        return 1;
    }
    struct termios raw;
    tcgetattr(slave, &raw);
    cfmakeraw(&raw);
    tcsetattr(slave, TCSANOW, &raw);
    tcsetattr(bridge.master, TCSANOW, &raw);
    fcntl(bridge.master, F_SETFL, fcntl(bridge.master, F_GETFL) | O_NONBLOCK);

    uint32_t flags = 0; /* no console echo of the UART, no host sleeps when the firmware polls it */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_output_hook,
                            &bridge);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook,
                            &bridge);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook,
                            &bridge);
    bridge.uart_input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    bridge.cycles_per_byte = CPU_HZ * 10u / 9600u; /* start, 8 data, stop */

    static decoder_t decoder;
    char port;
    int bit;
    pin_of(mcu, &port, &bit);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit), data_pin_hook, &decoder);

    printf("pty %s\n", slave_name);
    fflush(stdout);

    struct timespec start;
    clock_gettime(CLOCK_MONOTONIC, &start);
    for (unsigned long step = 1;; ++step) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "illuminator-sim: the firmware stopped (state %d)\n", state);
            return 1;
        }
        if (step % 256u != 0) {
            continue;
        }
        feed_uart(&bridge);
        keep_udre_while_idle(&bridge);
        report_frame_if_latched(&decoder);
        if (step % 65536u != 0) {
            continue;
        }
        double ahead = (double)avr->cycle / CPU_HZ - seconds_since(&start);
        if (ahead > 0.002) {
            usleep((useconds_t)(ahead * 1e6));
        }
        if (stdin_closed() || seconds_since(&start) > limit) {
            return 0;
        }
    }
}
