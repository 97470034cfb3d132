/* cac turntable firmware for the ATmega328P (Arduino Uno / Nano): protocol version 1 of
 * docs/protocol.md over the UART, a turntable axis and an optional camera rail driven by
 * step/dir drivers, homing on an index sensor / near-end switch, rail soft limits,
 * STOP/ESTOP/CLEAR/RESET, a hardware e-stop input, the BOOT banner, and a watchdog.
 * No dynamic allocation; every buffer is static and bounded. Configuration: config.h. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "config.h"
#include "motion.h"
#include "proto.h"

#define ESTOP_BIT _BV(PC0)

/* ---- reset cause ------------------------------------------------------------------------- */

#define RESET_MAGIC 0xB007C0DEUL
static uint32_t reset_magic __attribute__((section(".noinit")));
static uint8_t boot_flags __attribute__((section(".noinit")));

/* Runs before main and before .bss is cleared: save and clear MCUSR and stop a watchdog left
 * running by the reset (it stays enabled after a watchdog reset). Optiboot clears MCUSR itself
 * and hands its value over in r2. */
void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
    uint8_t r2;
    __asm__ volatile("mov %0, r2" : "=r"(r2));
    boot_flags = MCUSR ? MCUSR : (r2 & 0x0F);
    MCUSR = 0;
    wdt_disable();
}

static const char *boot_reason(void)
{
    if (boot_flags & _BV(WDRF)) {
        if (reset_magic == RESET_MAGIC)
            return PSTR("RESET"); /* our own RESET command reboots through the watchdog */
        return PSTR("WATCHDOG");
    }
    if (boot_flags & _BV(BORF))
        return PSTR("BROWNOUT");
    if (boot_flags & _BV(PORF))
        return PSTR("POWERON");
    return PSTR("RESET"); /* reset pin, DTR auto-reset, or a bootloader that hid the cause */
}

/* ---- UART: interrupt-driven ring buffers -------------------------------------------------- */

#define RX_SIZE 128
#define TX_SIZE 256
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;

ISR(USART_RX_vect)
{
    uint8_t st = UCSR0A;
    uint8_t b = UDR0;
    if (st & (_BV(FE0) | _BV(DOR0)))
        b = 0xFF; /* a broken byte: keep the line length right, the CRC will reject it */
    uint8_t next = (uint8_t)((rx_head + 1) % RX_SIZE);
    if (next != rx_tail) {
        rx_buf[rx_head] = b;
        rx_head = next;
    }
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint8_t)(tx_tail + 1); /* TX_SIZE is 256: wraps by itself */
}

static void uart_init(void)
{
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / (8 * UART_BAUD) - 1);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

static void tx_put(uint8_t b)
{
    while ((uint8_t)(tx_head + 1) == tx_tail)
        wdt_reset(); /* full: the UDRE interrupt drains it (~87 us a byte) */
    tx_buf[tx_head] = b;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        tx_head = (uint8_t)(tx_head + 1);
        UCSR0B |= _BV(UDRIE0);
    }
}

static void tx_line(const struct line *l)
{
    for (uint8_t i = 0; i < l->n; i++)
        tx_put((uint8_t)l->b[i]);
}

static void tx_flush(void)
{
    while (tx_head != tx_tail)
        wdt_reset();
    UCSR0A |= _BV(TXC0);
    while (!(UCSR0A & _BV(TXC0)) && (UCSR0B & _BV(TXEN0)))
        wdt_reset();
}

/* ---- device state ----------------------------------------------------------------------- */

enum { FAULT_NONE = 0, FAULT_ESTOP, FAULT_LIMIT, FAULT_STALL };
static const char FAULT_WORD[][6] PROTO_FLASH = {"NONE", "ESTOP", "LIMIT", "STALL"};
enum { END_REACHED = 0, END_STOPPED, END_ABORTED };
static const char END_WORD[][8] PROTO_FLASH = {"REACHED", "STOPPED", "ABORTED"};
enum { KIND_MOVE = 0, KIND_HOME };
enum { PHASE_BACKOFF = 0, PHASE_SEEK };

struct axis {
    uint8_t active; /* a motion command is in progress (MOV=1) */
    uint8_t kind, phase, end;
    uint8_t homed;
    uint16_t seq;      /* current or last motion command (SEQ=) */
    int32_t target;    /* TGT= in units */
    int32_t target_steps;
    uint32_t speed, accel; /* units/s, units/s^2 */
};

static struct axis axes[2];
static uint8_t fault;             /* latched fault */
static uint8_t fault_event;       /* FAULT event to send once the DONEs are out */
static uint8_t fault_event_axis;  /* 0 = none */
static uint8_t greeted;           /* HELLO seen since boot */
static uint8_t reset_requested;

static struct {
    uint8_t valid;
    uint16_t seq, crc;
    struct line reply;
} cache;

static const int32_t SPR[2] = {TABLE_STEPS_PER_REV, RAIL_STEPS_PER_REV};
static const int32_t UPR[2] = {TABLE_UNITS_PER_REV, RAIL_UM_PER_REV};
static const uint32_t MAX_SPEED[2] = {TABLE_MAX_SPEED, RAIL_MAX_SPEED};
static const uint32_t MAX_ACCEL[2] = {TABLE_MAX_ACCEL, RAIL_MAX_ACCEL};
static const uint32_t HOME_SPEED[2] = {TABLE_HOME_SPEED, RAIL_HOME_SPEED};

static int32_t div_round(int64_t n, int32_t d)
{
    return (int32_t)(n >= 0 ? (n + d / 2) / d : -((-n + d / 2) / d));
}

static int32_t units_to_steps(uint8_t a, int32_t u) { return div_round((int64_t)u * SPR[a], UPR[a]); }
static int32_t steps_to_units(uint8_t a, int32_t s) { return div_round((int64_t)s * UPR[a], SPR[a]); }

/* A rate in units/s (or /s^2) as steps/s, at least 1. */
static uint32_t rate_steps(uint8_t a, uint32_t v)
{
    uint32_t r = (uint32_t)((uint64_t)v * (uint32_t)SPR[a] / (uint32_t)UPR[a]);
    return r ? r : 1;
}

static uint8_t has_axis(uint8_t a) { return a == 1 || (a == 2 && HAVE_RAIL); }

/* POS=: the commanded target exactly when the axis stands on its step, else the step count
 * converted (so a reached move reports the target the host asked for). */
static int32_t position_units(uint8_t a)
{
    int32_t s = motion_pos(a);
    return s == axes[a].target_steps ? axes[a].target : steps_to_units(a, s);
}

static int32_t home_units(uint8_t a) { return a == 0 ? 0 : RAIL_MIN_UM; }

/* Trapezoid time in ms, rounded up (section 9). */
static uint32_t eta_ms(uint32_t d, uint32_t v, uint32_t acc)
{
    if (d == 0)
        return 0;
    if ((uint64_t)d * acc >= (uint64_t)v * v) {
        /* d/v + v/a = (d*a + v^2) / (v*a) seconds */
        uint64_t num = ((uint64_t)d * acc + (uint64_t)v * v) * 1000u;
        uint64_t den = (uint64_t)v * acc;
        uint64_t ms = (num + den - 1) / den;
        return ms > 0xFFFFFFFFu ? 0xFFFFFFFFu : (uint32_t)ms;
    }
    /* triangle: 2*sqrt(d/a) s; integer square root of 4e6*d/a ms^2, rounded up */
    uint64_t q = ((uint64_t)d * 4000000u + acc - 1) / acc;
    uint32_t r = 0;
    for (uint32_t bit = 1UL << 30; bit; bit >>= 1) {
        uint32_t t = r | bit;
        if ((uint64_t)t * t <= q)
            r = t;
    }
    if ((uint64_t)r * r < q)
        r++;
    return r;
}

/* Search distance and an upper bound of the homing time. */
static uint32_t home_search_steps(uint8_t a)
{
    if (a == 0)
        return (uint32_t)TABLE_STEPS_PER_REV * 11 / 10;
    return (uint32_t)units_to_steps(1, RAIL_MAX_UM - RAIL_MIN_UM) * 11 / 10 + RAIL_BACKOFF_STEPS;
}

static uint32_t home_rate(uint8_t a)
{
    uint32_t v = axes[a].speed < HOME_SPEED[a] ? axes[a].speed : HOME_SPEED[a];
    return rate_steps(a, v);
}

static uint32_t home_eta(uint8_t a)
{
    uint32_t backoff = a == 0 ? TABLE_INDEX_WIDTH_STEPS : RAIL_BACKOFF_STEPS;
    uint32_t steps = home_search_steps(a) + backoff;
    uint32_t rate = home_rate(a);
    uint32_t acc = rate_steps(a, axes[a].accel);
    uint64_t ms = (uint64_t)steps * 1000u / rate + 2u * ((uint64_t)rate * 1000u / acc) + 200u;
    return ms > 0xFFFFFFFFu ? 0xFFFFFFFFu : (uint32_t)ms;
}

/* ---- events ------------------------------------------------------------------------------ */

static void send_done(uint8_t a, uint8_t end)
{
    struct line l;
    proto_line_begin(&l, 0);
    proto_line_str(&l, PSTR("DONE SEQ="));
    proto_line_u32(&l, axes[a].seq);
    proto_line_str(&l, a == 0 ? PSTR(" AXIS=1 POS=") : PSTR(" AXIS=2 POS="));
    proto_line_i32(&l, position_units(a));
    proto_line_str(&l, PSTR(" END="));
    proto_line_str(&l, END_WORD[end]);
    proto_line_finish(&l);
    tx_line(&l);
}

static void send_fault(uint8_t code, uint8_t axis)
{
    struct line l;
    proto_line_begin(&l, 0);
    proto_line_str(&l, PSTR("FAULT CODE="));
    proto_line_str(&l, FAULT_WORD[code]);
    if (axis) {
        proto_line_str(&l, PSTR(" AXIS="));
        proto_line_u32(&l, axis);
    }
    proto_line_finish(&l);
    tx_line(&l);
}

/* Latch a fault: every axis halts at once and loses its homing; the interrupted motions end
 * with DONE END=ABORTED, then the FAULT event follows (both sent by service()). */
static void latch_fault(uint8_t code, uint8_t axis)
{
    for (uint8_t a = 0; a < 2; a++) {
        motion_halt(a);
        axes[a].homed = 0;
        if (axes[a].active)
            axes[a].end = END_ABORTED;
    }
    drivers_enable(0);
    fault = code;
    fault_event = code;
    fault_event_axis = axis;
}

static uint8_t estop_input(void) { return !(PINC & ESTOP_BIT); }

/* The e-stop button halts the steppers from its pin-change interrupt, without waiting for the
 * main loop. */
ISR(PCINT1_vect)
{
    if (estop_input()) {
        motion_halt(0);
        motion_halt(1);
        drivers_enable(0);
    }
}

/* ---- motion commands --------------------------------------------------------------------- */

static void begin_segment(uint8_t a, int8_t dir, uint32_t steps, uint32_t rate, uint8_t stop_on)
{
    drivers_enable(1);
    motion_start(a, dir, steps, rate, rate_steps(a, axes[a].accel), stop_on);
}

static const char *motion_refusal(uint8_t a)
{
    if (fault == FAULT_ESTOP)
        return PSTR("ESTOP");
    if (fault != FAULT_NONE)
        return PSTR("FAULT");
    if (axes[a].active)
        return PSTR("BUSY");
    return 0;
}

static void home_phase(uint8_t a, uint8_t phase)
{
    struct axis *x = &axes[a];
    x->phase = phase;
    /* The table approaches its index turning positively, the rail its near end negatively. */
    int8_t seek = a == 0 ? 1 : -1;
    if (phase == PHASE_BACKOFF)
        begin_segment(a, (int8_t)-seek, a == 0 ? TABLE_INDEX_WIDTH_STEPS : RAIL_BACKOFF_STEPS,
                      home_rate(a), STOP_ON_INACTIVE);
    else
        begin_segment(a, seek, home_search_steps(a), home_rate(a), STOP_ON_ACTIVE);
}

static const char *cmd_home(uint16_t seq, uint8_t a, uint32_t *eta)
{
    const char *e = motion_refusal(a);
    if (e)
        return e;
    struct axis *x = &axes[a];
    x->active = 1;
    x->kind = KIND_HOME;
    x->end = END_REACHED;
    x->homed = 0;
    x->seq = seq;
    x->target = home_units(a);
    x->target_steps = INT32_MIN; /* positions are unknown until the reference is found */
    *eta = home_eta(a);
    home_phase(a, motion_sensor_active(a) ? PHASE_BACKOFF : PHASE_SEEK);
    return 0;
}

static const char *cmd_move(uint16_t seq, uint8_t a, int64_t target, uint32_t *eta)
{
    const char *e = motion_refusal(a);
    if (e)
        return e;
    struct axis *x = &axes[a];
    if (!x->homed)
        return PSTR("NOTHOMED");
    if (target < INT32_MIN || target > INT32_MAX)
        return PSTR("RANGE");
    if (a == 1 && (target < RAIL_MIN_UM || target > RAIL_MAX_UM))
        return PSTR("LIMIT");
    int32_t from = position_units(a);
    int64_t d = target - from;
    int32_t tsteps = units_to_steps(a, (int32_t)target);
    int32_t dsteps = tsteps - motion_pos(a);
    *eta = eta_ms((uint32_t)(d < 0 ? -d : d), x->speed, x->accel);
    x->active = 1;
    x->kind = KIND_MOVE;
    x->end = END_REACHED;
    x->seq = seq;
    x->target = (int32_t)target;
    x->target_steps = tsteps;
    begin_segment(a, dsteps < 0 ? -1 : 1, (uint32_t)(dsteps < 0 ? -dsteps : dsteps),
                  rate_steps(a, x->speed), STOP_ON_NONE);
    return 0;
}

/* Follow each axis' segments: homing phases, DONE events, then a pending FAULT event. */
static void service(void)
{
    for (uint8_t a = 0; a < 2; a++) {
        struct axis *x = &axes[a];
        struct stepper *s = &steppers[a];
        if (!x->active || s->running)
            continue;
        if (x->kind == KIND_HOME && x->end == END_REACHED) {
            if (s->sensor_hit && x->phase == PHASE_BACKOFF) {
                home_phase(a, PHASE_SEEK);
                continue;
            }
            if (s->sensor_hit) {
                x->target_steps = units_to_steps(a, home_units(a));
                motion_set_pos(a, x->target_steps);
                x->homed = 1;
            } else {
                /* The reference was not found within the search range. */
                x->active = 0;
                send_done(a, END_ABORTED);
                latch_fault(FAULT_STALL, (uint8_t)(a + 1));
                continue;
            }
        }
        x->active = 0;
        send_done(a, x->end);
        if (!IDLE_KEEP_ENABLED && !axes[0].active && !axes[1].active)
            drivers_enable(0);
    }
    if (fault_event && !axes[0].active && !axes[1].active) {
        send_fault(fault_event, fault_event_axis);
        fault_event = 0;
    }
}

/* ---- command dispatch ---------------------------------------------------------------------- */

static void reply_err(struct line *l, const char *code)
{
    proto_line_str(l, PSTR("ERR "));
    proto_line_str(l, code);
}

static void execute(uint16_t seq, const struct command *c, struct line *l)
{
    uint8_t a = c->axis ? (uint8_t)(c->axis - 1) : 0;
    if (c->axis && !has_axis(c->axis))
        return reply_err(l, PSTR("NOAXIS"));
    if (!greeted && !proto_allowed_before_hello(c->kind))
        return reply_err(l, PSTR("BOOTED"));
    const char *e = 0;
    uint32_t eta = 0;
    switch (c->kind) {
    case CMD_HELLO:
        greeted = 1;
        proto_line_str(l, PSTR("OK PROTO=1 FW=" FW_NAME));
#if HAVE_RAIL
        proto_line_str(l, PSTR(" AXES=2 RAIL="));
        proto_line_i32(l, RAIL_MIN_UM);
        proto_line_str(l, PSTR(":"));
        proto_line_i32(l, RAIL_MAX_UM);
#else
        proto_line_str(l, PSTR(" AXES=1"));
#endif
        return;
    case CMD_PING:
        break;
    case CMD_SPEED:
    case CMD_ACCEL: {
        uint32_t v = (uint32_t)c->value;
        uint32_t max = c->kind == CMD_SPEED ? MAX_SPEED[a] : MAX_ACCEL[a];
        if (v == 0 || v > max)
            return reply_err(l, PSTR("RANGE"));
        if (c->kind == CMD_SPEED)
            axes[a].speed = v;
        else
            axes[a].accel = v;
        break;
    }
    case CMD_STATUS:
        proto_line_str(l, PSTR("OK POS="));
        proto_line_i32(l, position_units(a));
        proto_line_str(l, PSTR(" TGT="));
        proto_line_i32(l, axes[a].target);
        proto_line_str(l, axes[a].active ? PSTR(" MOV=1") : PSTR(" MOV=0"));
        proto_line_str(l, axes[a].homed ? PSTR(" HOMED=1 FAULT=") : PSTR(" HOMED=0 FAULT="));
        proto_line_str(l, FAULT_WORD[fault]);
        proto_line_str(l, PSTR(" SEQ="));
        proto_line_u32(l, axes[a].seq);
        return;
    case CMD_HOME:
        e = cmd_home(seq, a, &eta);
        goto moving;
    case CMD_MOVE_ABS:
        e = cmd_move(seq, a, c->value, &eta);
        goto moving;
    case CMD_MOVE_REL: {
        const char *r = motion_refusal(a);
        if (r)
            return reply_err(l, r);
        if (!axes[a].homed)
            return reply_err(l, PSTR("NOTHOMED"));
        e = cmd_move(seq, a, (int64_t)position_units(a) + c->value, &eta);
        goto moving;
    }
    case CMD_STOP:
        for (uint8_t i = 0; i < 2; i++) {
            if ((c->axis == 0 || i == a) && axes[i].active && axes[i].end == END_REACHED) {
                axes[i].end = END_STOPPED;
                motion_stop(i);
            }
        }
        break;
    case CMD_ESTOP:
        latch_fault(FAULT_ESTOP, 0);
        break;
    case CMD_CLEAR:
        if (estop_input())
            return reply_err(l, PSTR("ESTOP"));
        fault = FAULT_NONE;
        break;
    case CMD_RESET:
        reset_requested = 1;
        break;
    }
    proto_line_str(l, PSTR("OK"));
    return;
moving:
    if (e)
        return reply_err(l, e);
    proto_line_str(l, PSTR("OK ETA="));
    proto_line_u32(l, eta);
}

static void handle_line(const uint8_t *buf, uint8_t n)
{
    struct frame f;
    if (proto_parse_frame(buf, n, &f) != FRAME_OK || f.seq == 0)
        return; /* silent: a corrupted line's number cannot be trusted; events are not ours */
    if (cache.valid && cache.seq == f.seq && cache.crc == f.crc) {
        tx_line(&cache.reply); /* a retry: the same reply, nothing executed */
        return;
    }
    struct command c;
    struct line *l = &cache.reply;
    proto_line_begin(l, f.seq);
    switch (proto_parse_command(f.body, f.body_len, &c)) {
    case PARSE_OK:
        execute(f.seq, &c, l);
        break;
    case PARSE_BADCMD:
        reply_err(l, PSTR("BADCMD"));
        break;
    case PARSE_NOAXIS:
        reply_err(l, PSTR("NOAXIS"));
        break;
    default:
        reply_err(l, PSTR("BADARG"));
        break;
    }
    proto_line_finish(l);
    cache.valid = 1;
    cache.seq = f.seq;
    cache.crc = f.crc;
    tx_line(l);
}

/* Rail moves watch the near-end switch: found active far from where the rail believes it is,
 * steps were lost. */
static void check_rail_limit(void)
{
#if HAVE_RAIL
    struct axis *x = &axes[1];
    if (x->active && x->kind == KIND_MOVE && motion_sensor_active(1) &&
        motion_pos(1) > units_to_steps(1, RAIL_MIN_UM) + RAIL_LIMIT_MARGIN_STEPS)
        latch_fault(FAULT_LIMIT, 2);
#endif
}

static void reboot(void)
{
    tx_flush();
    reset_magic = RESET_MAGIC;
    cli();
    wdt_enable(WDTO_15MS);
    for (;;) {
    }
}

static struct assembler rx_asm;

int main(void)
{
    const char *reason = boot_reason();
    reset_magic = 0;
    motion_init();
    PORTC |= ESTOP_BIT; /* pull-up */
    DDRC &= (uint8_t)~ESTOP_BIT;
    PCMSK1 = _BV(PCINT8);
    PCICR = _BV(PCIE1);
    for (uint8_t a = 0; a < 2; a++) {
        axes[a].speed = a == 0 ? TABLE_DEFAULT_SPEED : RAIL_DEFAULT_SPEED;
        axes[a].accel = a == 0 ? TABLE_DEFAULT_ACCEL : RAIL_DEFAULT_ACCEL;
    }
    uart_init();
    proto_asm_clear(&rx_asm);
    sei();
    {
        struct line l;
        proto_line_begin(&l, 0);
        proto_line_str(&l, PSTR("BOOT PROTO=1 FW=" FW_NAME " REASON="));
        proto_line_str(&l, reason);
        proto_line_finish(&l);
        tx_line(&l);
    }
    if (estop_input())
        latch_fault(FAULT_ESTOP, 0);
    wdt_enable(WATCHDOG);
    for (;;) {
        wdt_reset();
        if (estop_input() && fault != FAULT_ESTOP)
            latch_fault(FAULT_ESTOP, 0);
        while (rx_tail != rx_head) {
            uint8_t b = rx_buf[rx_tail];
            rx_tail = (uint8_t)((rx_tail + 1) % RX_SIZE);
            uint8_t n;
            if (proto_asm_push(&rx_asm, b, &n) == ASM_LINE) {
                handle_line(rx_asm.buf, n);
                if (reset_requested)
                    reboot();
            }
            wdt_reset();
        }
        check_rail_limit();
        service();
        /* Sleep until the next interrupt (a byte, a step, the 1 ms tick). */
        set_sleep_mode(SLEEP_MODE_IDLE);
        cli();
        if (rx_tail == rx_head) {
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
