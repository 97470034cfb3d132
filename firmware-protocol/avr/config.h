/* Turntable firmware configuration: the one file to edit for another build.
 *
 * Pin map: the Arduino CNC Shield V3 layout (GRBL's), so an Uno + CNC shield + A4988/DRV8825
 * modules works as is; on a Nano or a bare breadboard wire the same Arduino pins.
 *   turntable = the shield's X axis, rail = its Y axis.
 *
 *   signal                 Arduino pin  AVR pin   level
 *   turntable STEP         D2           PD2       pulse high
 *   rail STEP              D3           PD3       pulse high
 *   turntable DIR          D5           PD5       high = positive
 *   rail DIR               D6           PD6       high = positive (away from the near end)
 *   drivers ENABLE         D8           PB0       low = enabled (A4988/DRV8825/TMC2209 EN)
 *   turntable index        D9 (X-)      PB1       active low, internal pull-up
 *   rail near-end switch   D10 (Y-)     PB2       active low, internal pull-up
 *   emergency stop         A0 (Abort)   PC0       active low, internal pull-up
 */
#ifndef CAC_CONFIG_H
#define CAC_CONFIG_H

#define FW_NAME "cac-avr-1.0" /* FW= in HELLO and BOOT: one word, at most 24 bytes */
#define UART_BAUD 115200UL

/* ---- turntable (axis 1): positions in millidegrees ---------------------------------------- */
#define TABLE_MOTOR_STEPS 200 /* full steps per motor revolution (1.8 degree motor) */
#define TABLE_MICROSTEPS 16   /* driver microstepping (MS1..MS3 jumpers) */
#define TABLE_REDUCTION_NUM 4 /* table turns REDUCTION_NUM/REDUCTION_DEN times slower than */
#define TABLE_REDUCTION_DEN 1 /* the motor (e.g. 80:20 teeth belt = 4/1) */
/* Microsteps per table revolution (must be a whole number): 12800 = 35.56 steps/degree. */
#define TABLE_STEPS_PER_REV                                                                    \
    ((int32_t)TABLE_MOTOR_STEPS * TABLE_MICROSTEPS * TABLE_REDUCTION_NUM / TABLE_REDUCTION_DEN)
#define TABLE_UNITS_PER_REV 360000L /* millidegrees per revolution */
#define TABLE_DEFAULT_SPEED 90000UL /* m°/s (restored at boot) */
#define TABLE_DEFAULT_ACCEL 180000UL /* m°/s² */
#define TABLE_MAX_SPEED 720000UL    /* m°/s: 25600 steps/s with the numbers above */
#define TABLE_MAX_ACCEL 2000000UL   /* m°/s² */
#define TABLE_HOME_SPEED 90000UL    /* m°/s, homing never runs faster (it stops dead on the index) */
#define TABLE_INDEX_WIDTH_STEPS 400 /* backing off an active index: at most this many steps */

/* ---- camera rail (axis 2): positions in micrometres ---------------------------------------- */
#define HAVE_RAIL 1
#define RAIL_MOTOR_STEPS 200
#define RAIL_MICROSTEPS 16
#define RAIL_UM_PER_REV 40000L /* GT2 belt, 20-tooth pulley: 40 mm per motor turn */
#define RAIL_STEPS_PER_REV ((int32_t)RAIL_MOTOR_STEPS * RAIL_MICROSTEPS) /* 80 steps/mm */
#define RAIL_MIN_UM 0L         /* soft limits; the near-end switch is at RAIL_MIN_UM */
#define RAIL_MAX_UM 400000L
#define RAIL_DEFAULT_SPEED 50000UL  /* µm/s */
#define RAIL_DEFAULT_ACCEL 100000UL /* µm/s² */
#define RAIL_MAX_SPEED 200000UL     /* 16000 steps/s */
#define RAIL_MAX_ACCEL 1000000UL
#define RAIL_HOME_SPEED 50000UL
#define RAIL_BACKOFF_STEPS 800 /* leaving an active switch before homing: at most this many */
/* A rail move that finds the near-end switch active more than this far from RAIL_MIN_UM has
 * lost steps: it halts and latches FAULT CODE=LIMIT AXIS=2. */
#define RAIL_LIMIT_MARGIN_STEPS 160

/* ---- motion engine -------------------------------------------------------------------------- */
#define STEP_TIMER_HZ 2000000UL /* Timer1 at F_CPU/8 */
#define RAMP_HZ 977UL           /* Timer0 ramp tick: F_CPU/64/256 = 976.56 Hz */
#define MIN_STEP_RATE 31UL      /* slowest step rate (16-bit compare interval at 2 MHz) */
#define STEP_PULSE_US 2         /* STEP high time (A4988 >= 1 us, DRV8825 >= 1.9 us) */
#define IDLE_KEEP_ENABLED 1     /* hold torque between moves (0: disable drivers when idle) */

/* ---- safety ---------------------------------------------------------------------------------- */
#define WATCHDOG WDTO_250MS

#endif
