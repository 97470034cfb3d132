/* Step generation: one Timer1 compare channel per axis fires each step (exact step timing, up
 * to ~40k steps/s per axis), a 1 kHz Timer0 tick ramps the speed (trapezoidal profile: constant
 * acceleration, cruise, deceleration planned from the remaining steps) and keeps the clock. */
#ifndef CAC_MOTION_H
#define CAC_MOTION_H

#include <stdint.h>

enum { STOP_ON_NONE = 0, STOP_ON_ACTIVE, STOP_ON_INACTIVE };

struct stepper {
    volatile int32_t pos;       /* steps since boot / since homing */
    volatile uint32_t remaining;
    volatile uint16_t interval; /* Timer1 ticks (0.5 us) between steps */
    volatile uint8_t running;
    volatile int8_t dir;
    volatile uint8_t stop_on;    /* stop at once when the axis' sensor becomes (in)active */
    volatile uint8_t sensor_hit; /* the last segment ended on its sensor */
    uint32_t v, vmax, dv;        /* Q16 steps/s; dv per ramp tick */
    uint32_t accel;              /* steps/s^2 */
    uint32_t max_rate;           /* fastest step rate reached in the segment (steps/s) */
};

extern struct stepper steppers[2];

void motion_init(void);
/* Start a segment of `steps` steps in direction dir (+1/-1). */
void motion_start(uint8_t axis, int8_t dir, uint32_t steps, uint32_t vmax, uint32_t accel,
                  uint8_t stop_on);
/* Decelerate to a halt at the segment's acceleration. */
void motion_stop(uint8_t axis);
/* Halt at once (no deceleration). */
void motion_halt(uint8_t axis);
int32_t motion_pos(uint8_t axis);
void motion_set_pos(uint8_t axis, int32_t pos);
uint8_t motion_sensor_active(uint8_t axis);
uint32_t clock_ms(void);
void drivers_enable(uint8_t on);

#endif
