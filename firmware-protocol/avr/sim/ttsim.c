/* ttsim: runs the compiled turntable firmware (an .elf) as an ATmega328P at 16 MHz in simavr
 * and plays the hardware around it:
 *   - the UART is bridged to a pseudo-terminal; its slave is symlinked at --link (printed as
 *     "PTY <path>"), so a host opens it like a USB serial port;
 *   - the STEP/DIR pins of both axes are counted (rising STEP edges, signed by DIR), and the
 *     ENABLE pin is watched (steps while the drivers are disabled are counted as errors);
 *   - the turntable's index sensor is driven from the simulated table angle (active low for
 *     --index-width steps after every multiple of --table-rev steps) and the rail's near-end
 *     switch from the simulated rail position (active low at or below 0);
 *   - the e-stop input can be pressed, and the chip reset (as a DTR auto-reset does), from the
 *     control channel.
 * Control: one command per line on stdin, one answer line on stdout:
 *   COUNTS            -> COUNTS us=<emulated us> tpos=.. tpulses=.. rpos=.. rpulses=..
 *                        en=<1 drivers enabled> bad=<steps while disabled> resets=.. wdt=..
 *                        tmin=<shortest table step interval, cycles> rmin=.. estop=<0|1>
 *                        rx=<bytes into the UART> tx=<bytes out of it> txdrop=..
 *                        trate=<most table steps in a 5 ms window, as steps/s> rrate=..
 *   STATE             -> STATE pc=<byte address> state=<simavr cpu state> sp=<stack pointer>
 *   MINRESET          -> OK   (restart the shortest-interval and step-rate measurements)
 *   ESTOP 0|1         -> OK   (release / press the e-stop button)
 *   NEAR auto|0|1     -> OK   (rail switch follows the rail / forced released / forced active)
 *   RESET             -> OK   (external reset: EXTRF, like the DTR auto-reset)
 *   QUIT              -> exits
 * Options: --elf PATH --link PATH [--speed S (emulated/real time, 0 = as fast as possible)]
 *          [--table-rev 12800] [--index-width 36] [--table-start STEPS] [--rail-start STEPS]
 *          [--pose-file PATH]
 * --pose-file: the physical position, "<table steps> <rail steps>\n" in fixed-width fields, is
 * rewritten in place after every step, so another process (the emulated camera of
 * tools/fakecam) can show the object as the mechanics hold it at that moment.
 * The physical positions survive chip resets (the mechanics do not move when the MCU reboots). */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_irq.h>

#define F_CPU 16000000ULL
#define MCUSR_ADDR 0x54
#define PORF 0
#define EXTRF 1

static avr_t *avr;
static int master = -1, slave = -1;

/* mechanics and pins */
static int64_t table_start, rail_start;
static int64_t tpos, rpos;         /* net steps counted on the STEP pins */
static uint64_t tpulses, rpulses;
static int tdir, rdir;             /* DIR pin levels */
static int enabled;                /* ENABLE low */
static uint64_t bad_steps;
static int64_t table_rev = 12800, index_width = 36;
static uint64_t last_tstep, last_rstep, tmin, rmin;
/* Step rate: the most steps in any 5 ms window (aligned), per axis. */
#define RATE_WINDOW (F_CPU / 200)
static uint64_t win_start[2], win_count[2], win_max[2];
static int estop_pressed;
static int near_mode = -1;         /* -1 auto, 0 released, 1 active */
static uint64_t resets, wdt_resets;
static uint64_t total_cycles, last_cycle;
static uint64_t rx_bytes, tx_bytes, tx_dropped, runs;
static avr_irq_t *index_irq, *near_irq, *estop_irq, *uart_in;
static int uart_xon = 1;
static int in_index = -1, in_near = -1, in_estop = -1; /* last levels driven */

static FILE *ctl_out; /* answers; stdout itself goes to stderr (simavr prints there) */

/* Emulated cycles since start (simavr versions differ in whether a reset zeroes avr->cycle). */
static uint64_t now_cycles(void)
{
    if (avr->cycle >= last_cycle)
        total_cycles += avr->cycle - last_cycle;
    last_cycle = avr->cycle;
    return total_cycles;
}

static int64_t table_phys(void) { return table_start + tpos; }
static int64_t rail_phys(void) { return rail_start + rpos; }

static void drive(avr_irq_t *irq, int *last, int level, int force)
{
    if (force || *last != level) {
        *last = level;
        if (force) /* simavr ignores a raise to the value the IRQ already holds */
            avr_raise_irq(irq, !level);
        avr_raise_irq(irq, level);
    }
}

/* simavr re-raises every input pin whose PORT bit (pull-up) is set to 1 whenever the firmware
 * writes that PORT register (e.g. PORTB for the ENABLE pin, or enabling the pull-up at boot),
 * unless the pin is declared externally driven: declare the sensors' levels, or a pressed
 * switch would read released after such a write. */
static void set_external(char port, uint8_t mask, uint8_t value)
{
    avr_ioport_external_t e = {.name = (unsigned)port, .mask = mask, .value = value};
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(port), &e);
}

static void drive_sensors(int force)
{
    int64_t m = table_phys() % table_rev;
    if (m < 0)
        m += table_rev;
    int index = m < index_width ? 0 : 1;
    int near = (near_mode < 0 ? rail_phys() <= 0 : near_mode) ? 0 : 1;
    int estop = estop_pressed ? 0 : 1;
    if (force || index != in_index || near != in_near)
        set_external('B', 0x06, (uint8_t)(index << 1 | near << 2)); /* PB1 index, PB2 near */
    if (force || estop != in_estop)
        set_external('C', 0x01, (uint8_t)estop); /* PC0 e-stop */
    drive(index_irq, &in_index, index, force);
    drive(near_irq, &in_near, near, force);
    drive(estop_irq, &in_estop, estop, force);
}

static int pose_fd = -1;

static void write_pose(void)
{
    if (pose_fd < 0)
        return;
    char line[48];
    int n = snprintf(line, sizeof line, "%20lld %20lld\n", (long long)table_phys(),
                     (long long)rail_phys());
    if (pwrite(pose_fd, line, (size_t)n, 0) != n)
        fprintf(stderr, "ttsim: cannot write the pose file: %s\n", strerror(errno));
}

static void on_step(int axis, uint32_t value)
{
    if (!value)
        return;
    uint64_t t = now_cycles();
    if (t - win_start[axis] >= RATE_WINDOW) {
        win_start[axis] = t - t % RATE_WINDOW;
        win_count[axis] = 0;
    }
    if (++win_count[axis] > win_max[axis])
        win_max[axis] = win_count[axis];
    if (!enabled)
        bad_steps++;
    if (axis == 0) {
        tpos += tdir ? 1 : -1;
        tpulses++;
        if (last_tstep && (tmin == 0 || t - last_tstep < tmin))
            tmin = t - last_tstep;
        last_tstep = t;
    } else {
        rpos += rdir ? 1 : -1;
        rpulses++;
        if (last_rstep && (rmin == 0 || t - last_rstep < rmin))
            rmin = t - last_rstep;
        last_rstep = t;
    }
    drive_sensors(0); /* the sensors see the new position before the firmware reads them */
    write_pose();
}

static void tstep_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; on_step(0, value); }
static void rstep_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; on_step(1, value); }
static void tdir_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; tdir = value != 0; }
static void rdir_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; rdir = value != 0; }
static void en_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; enabled = value == 0; }

static void uart_out_cb(avr_irq_t *irq, uint32_t value, void *p)
{
    (void)irq;
    (void)p;
    uint8_t b = (uint8_t)value;
    tx_bytes++;
    if (write(master, &b, 1) != 1)
        tx_dropped++; /* nobody reading and the tty buffer full: lost, like a real wire */
}
static void xon_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; if (value) uart_xon = 1; }
static void xoff_cb(avr_irq_t *irq, uint32_t value, void *p) { (void)irq; (void)p; if (value) uart_xon = 0; }

static void (*core_reset)(avr_t *);
static int in_control_reset;

/* Every chip reset (watchdog, or ours) passes here. */
static void on_reset(avr_t *a)
{
    if (core_reset)
        core_reset(a);
    resets++;
    if (!in_control_reset)
        wdt_resets++; /* the only reset the chip does by itself */
    in_index = in_near = in_estop = -1; /* pin states are cleared: drive them again */
}

static void no_sleep(avr_t *a, avr_cycle_count_t how_long) { (void)a; (void)how_long; }

static avr_irq_t *pin(char port, int n)
{
    return avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), n);
}

static void open_pty(const char *link)
{
    master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) || unlockpt(master)) {
        perror("ttsim: cannot create a pseudo-terminal");
        exit(2);
    }
    const char *name = ptsname(master);
    /* Keep a slave descriptor in raw mode: no echo of the firmware's output back into it, and
     * the master never sees a hangup while the host is away. */
    slave = open(name, O_RDWR | O_NOCTTY);
    struct termios t;
    if (slave < 0 || tcgetattr(slave, &t)) {
        fprintf(stderr, "ttsim: cannot open %s: %s\n", name, strerror(errno));
        exit(2);
    }
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(master, F_SETFL, O_NONBLOCK);
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.new", link);
    unlink(tmp);
    if (symlink(name, tmp) || rename(tmp, link)) {
        fprintf(stderr, "ttsim: cannot link %s to %s: %s\n", link, name, strerror(errno));
        exit(2);
    }
    fprintf(ctl_out, "PTY %s\n", name);
}

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void after_reset(uint8_t cause)
{
    avr->data[MCUSR_ADDR] |= (uint8_t)(1 << cause);
    drive_sensors(1);
}

static void control(char *line)
{
    char arg[32] = "";
    if (!strncmp(line, "COUNTS", 6)) {
        fprintf(ctl_out, "COUNTS us=%llu tpos=%lld tpulses=%llu rpos=%lld rpulses=%llu en=%d bad=%llu "
               "resets=%llu wdt=%llu tmin=%llu rmin=%llu estop=%d rx=%llu tx=%llu txdrop=%llu trate=%llu rrate=%llu\n",
               (unsigned long long)(now_cycles() / (F_CPU / 1000000)), (long long)tpos,
               (unsigned long long)tpulses, (long long)rpos, (unsigned long long)rpulses, enabled,
               (unsigned long long)bad_steps, (unsigned long long)resets,
               (unsigned long long)wdt_resets, (unsigned long long)tmin,
               (unsigned long long)rmin, estop_pressed, (unsigned long long)rx_bytes,
               (unsigned long long)tx_bytes, (unsigned long long)tx_dropped,
                (unsigned long long)(win_max[0] * 200), (unsigned long long)(win_max[1] * 200));
    } else if (!strncmp(line, "STATE", 5)) {
        fprintf(ctl_out, "STATE pc=0x%x state=%d sp=0x%x runs=%llu cycles=%llu\n", avr->pc,
                avr->state, avr->data[0x5d] | avr->data[0x5e] << 8, (unsigned long long)runs,
                (unsigned long long)now_cycles());
    } else if (!strncmp(line, "MINRESET", 8)) {
        tmin = rmin = last_tstep = last_rstep = 0;
        win_max[0] = win_max[1] = win_count[0] = win_count[1] = 0;
        fprintf(ctl_out, "OK\n");
    } else if (sscanf(line, "ESTOP %31s", arg) == 1) {
        estop_pressed = arg[0] == '1';
        drive_sensors(0);
        fprintf(ctl_out, "OK\n");
    } else if (sscanf(line, "NEAR %31s", arg) == 1) {
        near_mode = !strcmp(arg, "auto") ? -1 : arg[0] == '1';
        drive_sensors(0);
        fprintf(ctl_out, "OK\n");
    } else if (!strncmp(line, "RESET", 5)) {
        in_control_reset = 1;
        avr_reset(avr);
        in_control_reset = 0;
        after_reset(EXTRF);
        fprintf(ctl_out, "OK\n");
    } else if (!strncmp(line, "QUIT", 4)) {
        exit(0);
    } else {
        fprintf(ctl_out, "ERR unknown command: %s\n", line);
    }
    fflush(ctl_out);
}

static char ctl[256];
static size_t ctl_len;

static void poll_control(void)
{
    char buf[256];
    ssize_t n = read(0, buf, sizeof buf);
    if (n == 0)
        exit(0); /* the test process went away */
    for (ssize_t i = 0; i < n; i++) {
        if (buf[i] == '\n') {
            ctl[ctl_len] = 0;
            control(ctl);
            ctl_len = 0;
        } else if (ctl_len < sizeof ctl - 1) {
            ctl[ctl_len++] = buf[i];
        }
    }
}

static uint8_t host_buf[4096];
static size_t host_len, host_off;

static void poll_uart(void)
{
    if (host_off == host_len) {
        host_off = host_len = 0;
        ssize_t n = read(master, host_buf, sizeof host_buf);
        if (n > 0)
            host_len = (size_t)n;
    }
    while (host_off < host_len && uart_xon) {
        rx_bytes++;
        avr_raise_irq(uart_in, host_buf[host_off++]);
    }
}

int main(int argc, char **argv)
{
    const char *elf = 0, *link = 0, *pose = 0;
    double speed = 1.0;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--elf"))
            elf = argv[i + 1];
        else if (!strcmp(argv[i], "--link"))
            link = argv[i + 1];
        else if (!strcmp(argv[i], "--speed"))
            speed = atof(argv[i + 1]);
        else if (!strcmp(argv[i], "--table-rev"))
            table_rev = atoll(argv[i + 1]);
        else if (!strcmp(argv[i], "--index-width"))
            index_width = atoll(argv[i + 1]);
        else if (!strcmp(argv[i], "--table-start"))
            table_start = atoll(argv[i + 1]);
        else if (!strcmp(argv[i], "--rail-start"))
            rail_start = atoll(argv[i + 1]);
        else if (!strcmp(argv[i], "--pose-file"))
            pose = argv[i + 1];
        else {
            fprintf(stderr, "ttsim: unknown option %s\n", argv[i]);
            return 2;
        }
    }
    if (!elf || !link || table_rev <= 0) {
        fprintf(stderr, "usage: ttsim --elf FIRMWARE.elf --link PTY_SYMLINK [--speed S] "
                        "[--table-rev N] [--index-width N] [--table-start N] [--rail-start N] [--pose-file PATH]\n");
        return 2;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw)) {
        fprintf(stderr, "ttsim: cannot read the firmware %s\n", elf);
        return 2;
    }
    if (pose) {
        pose_fd = open(pose, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        if (pose_fd < 0) {
            fprintf(stderr, "ttsim: cannot create the pose file %s: %s\n", pose, strerror(errno));
            return 2;
        }
        write_pose();
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        fprintf(stderr, "ttsim: simavr has no atmega328p core\n");
        return 2;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->frequency = (uint32_t)F_CPU;
    avr->sleep = no_sleep; /* sleeping fast-forwards; the loop below keeps pace with real time */
    avr->log = LOG_ERROR;
    core_reset = avr->reset;
    avr->reset = on_reset;

    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_cb, 0);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            xon_cb, 0);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            xoff_cb, 0);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(pin('D', 2), tstep_cb, 0);
    avr_irq_register_notify(pin('D', 3), rstep_cb, 0);
    avr_irq_register_notify(pin('D', 5), tdir_cb, 0);
    avr_irq_register_notify(pin('D', 6), rdir_cb, 0);
    avr_irq_register_notify(pin('B', 0), en_cb, 0);
    index_irq = pin('B', 1);
    near_irq = pin('B', 2);
    estop_irq = pin('C', 0);

    ctl_out = fdopen(dup(1), "w");
    dup2(2, 1);
    open_pty(link);
    fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
    after_reset(PORF);
    last_cycle = avr->cycle;
    fprintf(ctl_out, "READY\n");
    fflush(ctl_out);

    double t0 = wall_s();
    for (;;) {
        /* Run 0.25 ms of emulated time, then serve the pty and the control channel. */
        uint64_t until = now_cycles() + F_CPU / 4000;
        while (now_cycles() < until) {
            int st = avr_run(avr);
            runs++;
            if (in_index < 0)
                drive_sensors(1);
            if (st == cpu_Done || st == cpu_Crashed) {
                fprintf(stderr, "ttsim: the firmware stopped (state %d) at pc 0x%x\n", st,
                        avr->pc);
                fprintf(ctl_out, "CRASHED\n");
                fflush(ctl_out);
                return 3;
            }
        }
        poll_uart();
        poll_control();
        if (speed > 0) {
            double ahead = (double)now_cycles() / F_CPU / speed - (wall_s() - t0);
            if (ahead > 0.001)
                usleep((useconds_t)(ahead * 1e6 > 2000 ? 2000 : ahead * 1e6));
        }
    }
}
