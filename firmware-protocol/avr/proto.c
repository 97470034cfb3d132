/* See proto.h. Mirrors the Rust crate firmware-protocol/ rule for rule; both are checked
 * against the shared vectors in firmware-protocol/tests/vectors.txt. */
#include "proto.h"

uint16_t proto_crc16(const uint8_t *p, size_t n)
{
    uint16_t crc = 0xFFFF;
    while (n--) {
        crc ^= (uint16_t)(*p++) << 8;
        for (uint8_t i = 0; i < 8; i++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

static int8_t hexval(uint8_t c)
{
    if (c >= '0' && c <= '9')
        return (int8_t)(c - '0');
    if (c >= 'A' && c <= 'F')
        return (int8_t)(c - 'A' + 10);
    return -1;
}

static uint8_t is_digit(char c) { return c >= '0' && c <= '9'; }

enum frame_status proto_parse_frame(const uint8_t *line, uint8_t n, struct frame *out)
{
    for (uint8_t i = 0; i < n; i++)
        if (line[i] < 0x20 || line[i] > 0x7E)
            return FRAME_NOTASCII;
    if (n < 6 || line[n - 6] != ' ' || line[n - 5] != '*')
        return FRAME_MISSINGCRC;
    uint16_t received = 0;
    for (uint8_t i = n - 4; i < n; i++) {
        int8_t d = hexval(line[i]);
        if (d < 0)
            return FRAME_MISSINGCRC;
        received = (uint16_t)((received << 4) | (uint8_t)d);
    }
    uint8_t len = n - 6;
    uint16_t computed = proto_crc16(line, len);
    if (computed != received)
        return FRAME_CRC;
    uint8_t sp = 0;
    while (sp < len && line[sp] != ' ')
        sp++;
    if (sp == len)
        return FRAME_EMPTYBODY;
    uint16_t seq = 0;
    if (sp == 1 && line[0] == '!') {
        seq = 0;
    } else {
        if (sp == 0 || sp > 5 || line[0] == '0')
            return FRAME_BADSEQ;
        uint32_t v = 0;
        for (uint8_t i = 0; i < sp; i++) {
            if (!is_digit((char)line[i]))
                return FRAME_BADSEQ;
            v = v * 10 + (uint32_t)(line[i] - '0');
        }
        if (v == 0 || v > 65535)
            return FRAME_BADSEQ;
        seq = (uint16_t)v;
    }
    if (sp + 1 >= len)
        return FRAME_EMPTYBODY;
    out->seq = seq;
    out->crc = computed;
    out->body = (const char *)line + sp + 1;
    out->body_len = (uint8_t)(len - sp - 1);
    return FRAME_OK;
}

static const char WORDS[CMD_COUNT][9] PROTO_FLASH = {
    "HELLO", "PING", "HOME", "MOVE_ABS", "MOVE_REL", "SPEED", "ACCEL",
    "STATUS", "STOP", "ESTOP", "CLEAR", "RESET",
};

uint8_t proto_allowed_before_hello(uint8_t kind)
{
    return kind == CMD_HELLO || kind == CMD_PING || kind == CMD_STATUS || kind == CMD_STOP ||
           kind == CMD_ESTOP;
}

static int8_t lookup(const char *w, uint8_t n)
{
    for (uint8_t k = 0; k < CMD_COUNT; k++) {
        const char *s = WORDS[k];
        uint8_t i = 0;
        while (i < n && proto_rd(s + i) && proto_rd(s + i) == w[i])
            i++;
        if (i == n && proto_rd(s + i) == 0)
            return (int8_t)k;
    }
    return -1;
}

/* Canonical digits: 1..10 digits, no leading zero unless the number is "0". */
static uint8_t canonical(const char *d, uint8_t n)
{
    if (n == 0 || n > 10)
        return 0;
    for (uint8_t i = 0; i < n; i++)
        if (!is_digit(d[i]))
            return 0;
    return !(n > 1 && d[0] == '0');
}

static uint32_t digits_value(const char *d, uint8_t n, uint8_t *overflow)
{
    uint32_t v = 0;
    *overflow = 0;
    for (uint8_t i = 0; i < n; i++) {
        uint8_t c = (uint8_t)(d[i] - '0');
        if (v > 429496729u || (v == 429496729u && c > 5))
            *overflow = 1;
        v = v * 10 + c;
    }
    return v;
}

uint8_t proto_parse_u32(const char *s, uint8_t n, uint32_t *out)
{
    uint8_t of;
    if (!canonical(s, n))
        return 0;
    uint32_t v = digits_value(s, n, &of);
    if (of)
        return 0;
    *out = v;
    return 1;
}

uint8_t proto_parse_i32(const char *s, uint8_t n, int32_t *out)
{
    uint8_t neg = n > 0 && s[0] == '-';
    const char *d = s + neg;
    uint8_t dn = n - neg;
    uint8_t of;
    if (!canonical(d, dn) || (neg && dn == 1 && d[0] == '0'))
        return 0;
    uint32_t v = digits_value(d, dn, &of);
    if (of)
        return 0;
    if (neg) {
        if (v > 2147483648u)
            return 0;
        *out = (int32_t)(0u - v);
    } else {
        if (v > 2147483647u)
            return 0;
        *out = (int32_t)v;
    }
    return 1;
}

/* "1"/"2" are axes; another canonical u32 is a missing axis; anything else is malformed. */
static enum parse_status parse_axis(const char *s, uint8_t n, uint8_t *axis)
{
    uint32_t v;
    if (n == 1 && (s[0] == '1' || s[0] == '2')) {
        *axis = (uint8_t)(s[0] - '0');
        return PARSE_OK;
    }
    return proto_parse_u32(s, n, &v) ? PARSE_NOAXIS : PARSE_BADARG;
}

enum parse_status proto_parse_command(const char *body, uint8_t n, struct command *out)
{
    const char *w[4];
    uint8_t wl[4];
    uint8_t count = 0, bad = 0, i = 0;
    /* Split on single spaces; empty words (doubled/leading/trailing spaces) or more than four
     * words are malformed. */
    while (1) {
        uint8_t start = i;
        while (i < n && body[i] != ' ')
            i++;
        if (i == start || count == 4) {
            bad = 1;
            break;
        }
        w[count] = body + start;
        wl[count] = (uint8_t)(i - start);
        count++;
        if (i == n)
            break;
        i++; /* skip the space */
    }
    if (bad) {
        uint8_t fl = 0;
        while (fl < n && body[fl] != ' ')
            fl++;
        return lookup(body, fl) < 0 ? PARSE_BADCMD : PARSE_BADARG;
    }
    int8_t kind = lookup(w[0], wl[0]);
    if (kind < 0)
        return PARSE_BADCMD;
    uint8_t args = count - 1;
    out->kind = (uint8_t)kind;
    out->axis = 0;
    out->value = 0;
    enum parse_status st;
    switch (kind) {
    case CMD_HELLO:
    case CMD_PING:
    case CMD_ESTOP:
    case CMD_CLEAR:
    case CMD_RESET:
        return args == 0 ? PARSE_OK : PARSE_BADARG;
    case CMD_STOP:
        if (args == 0)
            return PARSE_OK;
        if (args != 1)
            return PARSE_BADARG;
        return parse_axis(w[1], wl[1], &out->axis);
    case CMD_HOME:
    case CMD_STATUS:
        if (args != 1)
            return PARSE_BADARG;
        return parse_axis(w[1], wl[1], &out->axis);
    case CMD_MOVE_ABS:
    case CMD_MOVE_REL:
        if (args != 2)
            return PARSE_BADARG;
        if ((st = parse_axis(w[1], wl[1], &out->axis)) != PARSE_OK)
            return st;
        return proto_parse_i32(w[2], wl[2], &out->value) ? PARSE_OK : PARSE_BADARG;
    case CMD_SPEED:
    case CMD_ACCEL: {
        uint32_t v;
        if (args != 2)
            return PARSE_BADARG;
        if ((st = parse_axis(w[1], wl[1], &out->axis)) != PARSE_OK)
            return st;
        if (!proto_parse_u32(w[2], wl[2], &v))
            return PARSE_BADARG;
        out->value = (int32_t)v;
        return PARSE_OK;
    }
    default:
        return PARSE_BADCMD;
    }
}

static void put(struct line *l, char c)
{
    if (l->n < PROTO_MAX_LINE - 6)
        l->b[l->n++] = c;
}

void proto_line_str(struct line *l, const char *s)
{
    char c;
    while ((c = proto_rd(s++)) != 0)
        put(l, c);
}

void proto_line_u32(struct line *l, uint32_t v)
{
    char tmp[10];
    uint8_t k = 0;
    do {
        tmp[k++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    while (k)
        put(l, tmp[--k]);
}

void proto_line_i32(struct line *l, int32_t v)
{
    if (v < 0) {
        put(l, '-');
        proto_line_u32(l, 0u - (uint32_t)v);
    } else {
        proto_line_u32(l, (uint32_t)v);
    }
}

void proto_line_begin(struct line *l, uint16_t seq)
{
    l->n = 0;
    if (seq == 0)
        put(l, '!');
    else
        proto_line_u32(l, seq);
    put(l, ' ');
}

void proto_line_finish(struct line *l)
{
    static const char HEX[16] PROTO_FLASH = "0123456789ABCDEF";
    uint16_t crc = proto_crc16((const uint8_t *)l->b, l->n);
    l->b[l->n++] = ' ';
    l->b[l->n++] = '*';
    for (int8_t s = 12; s >= 0; s -= 4)
        l->b[l->n++] = proto_rd(HEX + ((crc >> s) & 0xF));
    l->b[l->n++] = '\n';
}

void proto_asm_clear(struct assembler *a)
{
    a->len = 0;
    a->overflowed = 0;
}

enum asm_status proto_asm_push(struct assembler *a, uint8_t byte, uint8_t *n)
{
    if (byte == '\n') {
        uint8_t len = a->len;
        uint8_t over = a->overflowed;
        a->len = 0;
        a->overflowed = 0;
        if (over)
            return ASM_TOOLONG;
        if (len > 0 && a->buf[len - 1] == '\r')
            len--;
        if (len == 0)
            return ASM_NONE;
        *n = len;
        return ASM_LINE;
    }
    if (a->overflowed)
        return ASM_NONE;
    if (a->len == PROTO_MAX_LINE) {
        a->overflowed = 1;
        a->len = 0;
        return ASM_NONE;
    }
    a->buf[a->len++] = byte;
    return ASM_NONE;
}
