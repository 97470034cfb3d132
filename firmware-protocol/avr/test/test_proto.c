/* Host unit test of the firmware's protocol code (proto.c) against the vectors shared with the
 * Rust crate: firmware-protocol/tests/vectors.txt. Usage: test_proto VECTORS_FILE.
 * Prints every failure and a summary; exit status 1 on any failure, 2 if the file is unusable. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "proto.h"

static int failures, checked;

/* Undo the file's escapes (\\ \n \r \t \xNN) in place; returns the length. */
static size_t unescape(char *s)
{
    size_t o = 0;
    for (size_t i = 0; s[i]; i++) {
        if (s[i] != '\\') {
            s[o++] = s[i];
            continue;
        }
        char c = s[++i];
        if (c == 'n')
            s[o++] = '\n';
        else if (c == 'r')
            s[o++] = '\r';
        else if (c == 't')
            s[o++] = '\t';
        else if (c == '\\')
            s[o++] = '\\';
        else if (c == 'x') {
            char hex[3] = {s[i + 1], s[i + 2], 0};
            s[o++] = (char)strtol(hex, 0, 16);
            i += 2;
        } else {
            fprintf(stderr, "bad escape \\%c\n", c);
            exit(2);
        }
    }
    s[o] = 0;
    return o;
}

static void fail(int lineno, const char *what, const char *got, const char *want)
{
    failures++;
    printf("vectors.txt:%d: %s: got \"%s\", want \"%s\"\n", lineno, what, got, want);
}

static const char *FRAME_ERR[] = {"OK", "NOTASCII", "MISSINGCRC", "CRC", "BADSEQ", "EMPTYBODY"};
static const char *PARSE_ERR[] = {"OK", "BADCMD", "BADARG", "NOAXIS"};
static const char *WORD[] = {"HELLO", "PING", "HOME", "MOVE_ABS", "MOVE_REL", "SPEED",
                             "ACCEL", "STATUS", "STOP", "ESTOP", "CLEAR", "RESET"};

/* Rebuild a device line from its content with the firmware's line builder. */
static void check_encoding(int lineno, const char *full)
{
    size_t n = strlen(full);
    if (n < 6) {
        fail(lineno, "encode", full, "a line");
        return;
    }
    char content[128];
    memcpy(content, full, n - 6);
    content[n - 6] = 0;
    struct line l;
    l.n = 0;
    for (size_t i = 0; content[i] && l.n < PROTO_MAX_LINE; i++)
        l.b[l.n++] = content[i];
    proto_line_finish(&l);
    char want[128];
    snprintf(want, sizeof want, "%s\n", full);
    if (l.n != strlen(want) || memcmp(l.b, want, l.n)) {
        char got[128];
        memcpy(got, l.b, l.n);
        got[l.n] = 0;
        fail(lineno, "encode", got, want);
    }
    /* and the firmware's own frame check accepts it */
    struct frame f;
    if (proto_parse_frame((const uint8_t *)full, (uint8_t)n, &f) != FRAME_OK)
        fail(lineno, "frame of encoded line", "rejected", "OK");
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: test_proto VECTORS_FILE\n");
        return 2;
    }
    FILE *fp = fopen(argv[1], "r");
    if (!fp) {
        perror(argv[1]);
        return 2;
    }
    char buf[2048];
    int lineno = 0;
    int kinds[6] = {0};
    while (fgets(buf, sizeof buf, fp)) {
        lineno++;
        buf[strcspn(buf, "\n")] = 0;
        if (!buf[0] || buf[0] == '#')
            continue;
        char *f[4] = {0};
        int nf = 0;
        char *p = buf;
        while (nf < 4) {
            f[nf++] = p;
            char *tab = strchr(p, '\t');
            if (!tab)
                break;
            *tab = 0;
            p = tab + 1;
        }
        checked++;
        char got[512];
        if (!strcmp(f[0], "crc") && nf == 3) {
            kinds[0]++;
            size_t n = unescape(f[1]);
            snprintf(got, sizeof got, "%04X", proto_crc16((const uint8_t *)f[1], n));
            if (strcmp(got, f[2]))
                fail(lineno, "crc", got, f[2]);
        } else if (!strcmp(f[0], "frame") && nf == 3) {
            kinds[1]++;
            size_t n = unescape(f[1]);
            struct frame fr;
            enum frame_status st = proto_parse_frame((const uint8_t *)f[1], (uint8_t)n, &fr);
            if (st == FRAME_OK) {
                char seq[8];
                if (fr.seq)
                    snprintf(seq, sizeof seq, "%u", fr.seq);
                else
                    strcpy(seq, "!");
                snprintf(got, sizeof got, "OK %s %.*s", seq, fr.body_len, fr.body);
            } else {
                snprintf(got, sizeof got, "ERR %s", FRAME_ERR[st]);
            }
            if (strcmp(got, f[2]))
                fail(lineno, "frame", got, f[2]);
        } else if (!strcmp(f[0], "command") && nf == 3) {
            kinds[2]++;
            size_t n = unescape(f[1]);
            struct command c;
            enum parse_status st = proto_parse_command(f[1], (uint8_t)n, &c);
            if (st != PARSE_OK) {
                snprintf(got, sizeof got, "ERR %s", PARSE_ERR[st]);
            } else {
                int k = snprintf(got, sizeof got, "%s", WORD[c.kind]);
                if (c.axis)
                    k += snprintf(got + k, sizeof got - k, " %u", c.axis);
                if (c.kind == CMD_SPEED || c.kind == CMD_ACCEL)
                    snprintf(got + k, sizeof got - k, " %lu", (unsigned long)(uint32_t)c.value);
                else if (c.kind == CMD_MOVE_ABS || c.kind == CMD_MOVE_REL)
                    snprintf(got + k, sizeof got - k, " %ld", (long)c.value);
            }
            if (strcmp(got, f[2]))
                fail(lineno, "command", got, f[2]);
        } else if (!strcmp(f[0], "stream") && nf >= 2) {
            kinds[3]++;
            size_t n = unescape(f[1]);
            char want[1024] = "";
            if (nf == 3) {
                strcpy(want, f[2]);
                unescape(want);
            }
            struct assembler a;
            proto_asm_clear(&a);
            size_t k = 0;
            got[0] = 0;
            for (size_t i = 0; i < n; i++) {
                uint8_t len;
                enum asm_status st = proto_asm_push(&a, (uint8_t)f[1][i], &len);
                if (st == ASM_NONE)
                    continue;
                if (k)
                    got[k++] = '|';
                if (st == ASM_TOOLONG) {
                    memcpy(got + k, "TOOLONG", 7);
                    k += 7;
                } else {
                    memcpy(got + k, a.buf, len);
                    k += len;
                }
                got[k] = 0;
            }
            if (strcmp(got, want))
                fail(lineno, "stream", got, want);
        } else if (!strcmp(f[0], "reply") && nf == 3) {
            kinds[4]++;
            check_encoding(lineno, f[2]);
        } else if (!strcmp(f[0], "event") && nf == 2) {
            kinds[5]++;
            check_encoding(lineno, f[1]);
        } else {
            fprintf(stderr, "vectors.txt:%d: unknown vector kind or field count\n", lineno);
            return 2;
        }
    }
    fclose(fp);
    printf("test_proto: %d vectors (%d crc, %d frame, %d command, %d stream, %d reply, %d event), "
           "%d failures\n",
           checked, kinds[0], kinds[1], kinds[2], kinds[3], kinds[4], kinds[5], failures);
    for (int i = 0; i < 6; i++)
        if (kinds[i] == 0) {
            printf("test_proto: no vectors of some kind: the file is incomplete\n");
            return 1;
        }
    return failures ? 1 : 0;
}
