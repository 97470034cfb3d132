/* Protocol v1 encoding for the AVR firmware (docs/protocol.md): CRC-16/CCITT-FALSE, line
 * framing, command parsing and reply/event line building. Plain C99 with no hardware access,
 * so the same file is compiled for the ATmega328P and for the host unit test (test/). */
#ifndef CAC_PROTO_H
#define CAC_PROTO_H

#include <stdint.h>
#include <stddef.h>

/* Constant strings live in flash on the AVR (2 KB of RAM is precious). */
#ifdef __AVR__
#include <avr/pgmspace.h>
#define PROTO_FLASH PROGMEM
#define proto_rd(p) ((char)pgm_read_byte(p))
#else
#define PROTO_FLASH
#define PSTR(s) (s)
#define proto_rd(p) (*(const char *)(p))
#endif

#define PROTO_MAX_LINE 96 /* bytes per line, without the '\n' ('\r' counts) */

uint16_t proto_crc16(const uint8_t *p, size_t n);

/* Frame check result (the device stays silent on everything but FRAME_OK). */
enum frame_status {
    FRAME_OK = 0,
    FRAME_NOTASCII,   /* a byte outside 0x20..0x7E */
    FRAME_MISSINGCRC, /* no " *XXXX" suffix with uppercase hex */
    FRAME_CRC,        /* CRC mismatch */
    FRAME_BADSEQ,     /* sequence field neither "!" nor 1..65535 without leading zeros */
    FRAME_EMPTYBODY   /* nothing after the sequence field */
};

struct frame {
    uint16_t seq;     /* 0 for an event line ("!") */
    uint16_t crc;     /* CRC of the content (everything before " *") */
    const char *body; /* points into the line */
    uint8_t body_len;
};

/* Check one line (without "\r\n"). */
enum frame_status proto_parse_frame(const uint8_t *line, uint8_t n, struct frame *out);

enum cmd_kind {
    CMD_HELLO, CMD_PING, CMD_HOME, CMD_MOVE_ABS, CMD_MOVE_REL, CMD_SPEED, CMD_ACCEL,
    CMD_STATUS, CMD_STOP, CMD_ESTOP, CMD_CLEAR, CMD_RESET, CMD_COUNT
};

/* Why a well-framed body is not a valid command: the ERR code the device replies. */
enum parse_status { PARSE_OK = 0, PARSE_BADCMD, PARSE_BADARG, PARSE_NOAXIS };

struct command {
    uint8_t kind;  /* enum cmd_kind */
    uint8_t axis;  /* 1 or 2; 0 = none (STOP without argument, commands without axis) */
    int32_t value; /* position/delta (i32), or speed/accel (u32 stored as its bits) */
};

enum parse_status proto_parse_command(const char *body, uint8_t n, struct command *out);
/* Whether a freshly booted device accepts the command before HELLO (section 10). */
uint8_t proto_allowed_before_hello(uint8_t kind);

/* Strict decimal numbers (section 2): no sign on u32, no leading zeros, no "-0". Return 1 on
 * success. */
uint8_t proto_parse_i32(const char *s, uint8_t n, int32_t *out);
uint8_t proto_parse_u32(const char *s, uint8_t n, uint32_t *out);

/* A line being built: "<seq> BODY", then proto_line_finish appends " *CRC\n". The content is
 * bounded by PROTO_MAX_LINE; anything longer is cut (the firmware's lines are far shorter). */
struct line {
    char b[PROTO_MAX_LINE + 2];
    uint8_t n;
};

void proto_line_begin(struct line *l, uint16_t seq); /* seq 0 = event ("!") */
void proto_line_str(struct line *l, const char *s); /* s in flash: PSTR("...") */
void proto_line_i32(struct line *l, int32_t v);
void proto_line_u32(struct line *l, uint32_t v);
void proto_line_finish(struct line *l);

/* Splits the byte stream into lines (section 2): '\n' ends a line, one '\r' before it is
 * removed, empty lines are skipped, a line longer than PROTO_MAX_LINE is discarded up to its
 * '\n' and reported once as ASM_TOOLONG. */
struct assembler {
    uint8_t buf[PROTO_MAX_LINE];
    uint8_t len;
    uint8_t overflowed;
};

enum asm_status { ASM_NONE = 0, ASM_LINE, ASM_TOOLONG };

void proto_asm_clear(struct assembler *a);
/* Feed one byte; on ASM_LINE the line is a->buf[0 .. *n). */
enum asm_status proto_asm_push(struct assembler *a, uint8_t byte, uint8_t *n);

#endif
