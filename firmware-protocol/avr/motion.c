/* See motion.h. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>
#include <util/delay.h>

#include "config.h"
#include "motion.h"

struct stepper steppers[2];
static volatile uint32_t ms_ticks;

#define STEP_BIT0 _BV(PD2)
#define STEP_BIT1 _BV(PD3)
#define DIR_BIT0 _BV(PD5)
#define DIR_BIT1 _BV(PD6)
#define EN_BIT _BV(PB0)
#define INDEX_BIT _BV(PB1)
#define NEAR_BIT _BV(PB2)

void drivers_enable(uint8_t on)
{
    if (on)
        PORTB &= (uint8_t)~EN_BIT; /* active low */
    else
        PORTB |= EN_BIT;
}

uint8_t motion_sensor_active(uint8_t axis)
{
    return !(PINB & (axis == 0 ? INDEX_BIT : NEAR_BIT));
}

void motion_init(void)
{
    PORTB |= EN_BIT; /* drivers off until the first motion: never move on our own after boot */
    DDRB |= EN_BIT;
    DDRD |= STEP_BIT0 | STEP_BIT1 | DIR_BIT0 | DIR_BIT1;
    PORTB |= INDEX_BIT | NEAR_BIT; /* pull-ups on the active-low sensors */
    DDRB &= (uint8_t)~(INDEX_BIT | NEAR_BIT);
    /* Timer1: free running at F_CPU/8, one compare channel per axis. */
    TCCR1A = 0;
    TCCR1B = _BV(CS11);
    TIMSK1 = 0;
    /* Timer0: overflow at F_CPU/64/256 = 976.5625 Hz. (Not Timer0: simavr emulates Timer0,
     * the one with an asynchronous clock option, cycle by cycle, 20 times slower.) */
    TCCR0A = 0;
    TCCR0B = _BV(CS01) | _BV(CS00);
    TIMSK0 = _BV(TOIE0);
}

uint32_t clock_ms(void)
{
    uint32_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { t = ms_ticks; }
    return t;
}

int32_t motion_pos(uint8_t axis)
{
    int32_t p;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { p = steppers[axis].pos; }
    return p;
}

void motion_set_pos(uint8_t axis, int32_t pos)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { steppers[axis].pos = pos; }
}

static uint16_t interval_for(uint32_t v_q16)
{
    uint32_t rate = v_q16 >> 16;
    if (rate < MIN_STEP_RATE)
        rate = MIN_STEP_RATE;
    uint32_t iv = STEP_TIMER_HZ / rate;
    return iv > 65535u ? 65535u : (uint16_t)iv;
}

void motion_start(uint8_t axis, int8_t dir, uint32_t steps, uint32_t vmax, uint32_t accel,
                  uint8_t stop_on)
{
    struct stepper *s = &steppers[axis];
    motion_halt(axis);
    uint8_t dbit = axis == 0 ? DIR_BIT0 : DIR_BIT1;
    if (dir > 0)
        PORTD |= dbit;
    else
        PORTD &= (uint8_t)~dbit;
    if (vmax < MIN_STEP_RATE)
        vmax = MIN_STEP_RATE;
    if (vmax > 40000)
        vmax = 40000;
    if (accel < 1)
        accel = 1;
    s->dir = dir;
    s->stop_on = stop_on;
    s->sensor_hit = 0;
    s->accel = accel;
    s->vmax = vmax << 16;
    s->v = (uint32_t)MIN_STEP_RATE << 16;
    uint32_t dv = (uint32_t)(((uint64_t)accel << 16) / RAMP_HZ);
    s->dv = dv ? dv : 1;
    s->max_rate = MIN_STEP_RATE;
    if (steps == 0)
        return;
    uint16_t iv = interval_for(s->v);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        s->interval = iv;
        s->remaining = steps;
        s->running = 1;
        /* First step 20 us from now (DIR setup time is 200 ns for the usual drivers). */
        if (axis == 0) {
            OCR1A = TCNT1 + 40;
            TIFR1 = _BV(OCF1A);
            TIMSK1 |= _BV(OCIE1A);
        } else {
            OCR1B = TCNT1 + 40;
            TIFR1 = _BV(OCF1B);
            TIMSK1 |= _BV(OCIE1B);
        }
    }
}

void motion_halt(uint8_t axis)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        steppers[axis].running = 0;
        steppers[axis].remaining = 0;
        TIMSK1 &= (uint8_t) ~(axis == 0 ? _BV(OCIE1A) : _BV(OCIE1B));
    }
}

static uint32_t stop_distance(const struct stepper *s)
{
    uint32_t vs = s->v >> 16;
    return vs * vs / (2 * s->accel) + vs / RAMP_HZ + 1;
}

void motion_stop(uint8_t axis)
{
    struct stepper *s = &steppers[axis];
    struct stepper copy;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        copy.v = s->v;
        copy.accel = s->accel;
    }
    uint32_t d = stop_distance(&copy);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        s->stop_on = STOP_ON_NONE;
        if (s->running && s->remaining > d)
            s->remaining = d;
    }
}

/* One step on `axis`: pulse, count, check the sensor, schedule the next. */
static inline void step(uint8_t axis, uint8_t step_bit, volatile uint16_t *ocr, uint8_t ocie)
{
    struct stepper *s = &steppers[axis];
    if (!s->running) {
        TIMSK1 &= (uint8_t)~ocie;
        return;
    }
    PORTD |= step_bit;
    s->pos += s->dir;
    uint32_t r = s->remaining - 1;
    _delay_us(STEP_PULSE_US);
    PORTD &= (uint8_t)~step_bit;
    uint8_t on = s->stop_on;
    if (on) {
        uint8_t act = motion_sensor_active(axis);
        if ((on == STOP_ON_ACTIVE && act) || (on == STOP_ON_INACTIVE && !act)) {
            s->sensor_hit = 1;
            r = 0;
        }
    }
    s->remaining = r;
    if (r == 0) {
        s->running = 0;
        TIMSK1 &= (uint8_t)~ocie;
        return;
    }
    /* Next step one interval after this one was due; if this interrupt ran so late that the
     * time has passed, soon (a compare in the past would wait a whole timer wrap). */
    uint16_t due = *ocr, iv = s->interval;
    uint16_t late = (uint16_t)(TCNT1 - due);
    *ocr = (uint32_t)late + 16 >= iv ? (uint16_t)(TCNT1 + 16) : (uint16_t)(due + iv);
}

ISR(TIMER1_COMPA_vect) { step(0, STEP_BIT0, &OCR1A, _BV(OCIE1A)); }
ISR(TIMER1_COMPB_vect) { step(1, STEP_BIT1, &OCR1B, _BV(OCIE1B)); }

/* Ramp tick: interruptible, so that step pulses are not delayed by the divisions. */
ISR(TIMER0_OVF_vect, ISR_NOBLOCK)
{
    ms_ticks++;
    for (uint8_t a = 0; a < 2; a++) {
        struct stepper *s = &steppers[a];
        uint32_t rem;
        uint8_t run;
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
        {
            rem = s->remaining;
            run = s->running;
        }
        if (!run)
            continue;
        const uint32_t vmin = (uint32_t)MIN_STEP_RATE << 16;
        if (rem <= stop_distance(s))
            s->v = s->v > s->dv + vmin ? s->v - s->dv : vmin;
        else if (s->v < s->vmax)
            s->v = s->vmax - s->v > s->dv ? s->v + s->dv : s->vmax;
        else if (s->v > s->vmax)
            s->v = s->v - s->vmax > s->dv ? s->v - s->dv : s->vmax;
        uint16_t iv = interval_for(s->v);
        uint32_t rate = s->v >> 16;
        if (rate > s->max_rate)
            s->max_rate = rate;
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { s->interval = iv; }
    }
}
