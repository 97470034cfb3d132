/*
 * probe.c - test client for fakecam.so (not shipped; a developer check).
 *
 * Build: cc -O2 -Wall -Wextra -o probe probe.c
 * Run:   FAKECAM_DEV=/dev/video7 FAKECAM_BANK=/tmp/bank LD_PRELOAD=./fakecam.so \
 *            ./probe [MJPG|YUYV] [W H] [frames]
 *
 * Opens the node, enumerates everything, sets the format and 15 fps, locks
 * exposure/WB/focus manual, streams with 4 MMAP buffers and checks each frame
 * (JPEG: FFD8 and no FFC4 unless FAKECAM_KEEP_DHT=1; YUYV: bytesused = 2wh,
 * and, with PROBE_EXPECT=file, identical to that bank file).  On a poll
 * timeout (stall) it restarts the stream once; on POLLERR|POLLHUP (unplug) it
 * closes, waits for the node to come back and streams a few frames again.
 * PROBE_DUMP=file writes the first good frame there; PROBE_AUTO=1 leaves the
 * controls on auto; PROBE_NOPOLL=1 blocks in DQBUF instead of polling.
 */
#include <errno.h>
#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <sys/select.h>
#include <time.h>
#include <unistd.h>

enum { NBUF = 4 };
enum outcome { DONE, UNPLUGGED, FAILED };

struct cam {
	int fd;
	uint32_t fourcc;
	unsigned w, h, nbufs;
	void *ptr[8];
	size_t len[8];
	int bad_frames, restarted;
	double last_ts;
};

static const char *dev_path;

static double now_ms(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static const char *cc(uint32_t f)
{
	static char s[5];
	memcpy(s, &f, 4);
	s[4] = 0;
	return s;
}

static int xioctl(int fd, unsigned long req, void *arg, const char *name)
{
	int r = ioctl(fd, req, arg);
	if (r < 0)
		printf("  %s: %s\n", name, strerror(errno));
	return r;
}

static void expect_errno(int fd, unsigned long req, void *arg, const char *what, int want)
{
	int r = ioctl(fd, req, arg);
	printf("  %-40s -> %s (%s)\n", what, r < 0 ? strerror(errno) : "ok",
	       (r < 0 && errno == want) || (r == 0 && want == 0) ? "as expected" : "UNEXPECTED");
}

static void enum_formats(int fd)
{
	struct v4l2_fmtdesc d = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };
	for (d.index = 0; ioctl(fd, VIDIOC_ENUM_FMT, &d) == 0; d.index++) {
		struct v4l2_frmsizeenum s = { .pixel_format = d.pixelformat };
		printf("  format %u: %s '%s' flags %#x\n", d.index, cc(d.pixelformat),
		       d.description, d.flags);
		for (s.index = 0; ioctl(fd, VIDIOC_ENUM_FRAMESIZES, &s) == 0; s.index++) {
			struct v4l2_frmivalenum iv = { .pixel_format = d.pixelformat,
				.width = s.discrete.width, .height = s.discrete.height };
			printf("    %ux%u:", s.discrete.width, s.discrete.height);
			for (iv.index = 0; ioctl(fd, VIDIOC_ENUM_FRAMEINTERVALS, &iv) == 0; iv.index++)
				printf(" %u/%u", iv.discrete.numerator, iv.discrete.denominator);
			printf("\n");
		}
	}
}

static void enum_controls(int fd)
{
	struct v4l2_queryctrl q = { .id = V4L2_CTRL_FLAG_NEXT_CTRL };
	while (ioctl(fd, VIDIOC_QUERYCTRL, &q) == 0) {
		struct v4l2_control c = { .id = q.id };
		ioctl(fd, VIDIOC_G_CTRL, &c);
		printf("  ctrl %#x '%s' type %u %d..%d/%d def %d flags %#x value %d\n", q.id,
		       q.name, q.type, q.minimum, q.maximum, q.step, q.default_value, q.flags, c.value);
		if (q.type == V4L2_CTRL_TYPE_MENU) {
			struct v4l2_querymenu m = { .id = q.id };
			for (m.index = q.minimum; m.index <= (uint32_t)q.maximum; m.index++)
				if (ioctl(fd, VIDIOC_QUERYMENU, &m) == 0)
					printf("    menu %u '%s'\n", m.index, m.name);
		}
		q.id |= V4L2_CTRL_FLAG_NEXT_CTRL;
	}
}

static int set_ctrl(int fd, uint32_t id, int v)
{
	struct v4l2_control c = { .id = id, .value = v };
	int r = ioctl(fd, VIDIOC_S_CTRL, &c);
	printf("  S_CTRL %#x = %d -> %s, now %d\n", id, v, r ? strerror(errno) : "ok", c.value);
	return r;
}

static int get_ctrl(int fd, uint32_t id)
{
	struct v4l2_control c = { .id = id };
	ioctl(fd, VIDIOC_G_CTRL, &c);
	return c.value;
}

static void check_controls(int fd)
{
	struct v4l2_control c = { .id = V4L2_CID_EXPOSURE_ABSOLUTE, .value = 300 };
	expect_errno(fd, VIDIOC_S_CTRL, &c, "S_CTRL exposure while auto", EACCES);
	c.id = 0x12345;
	expect_errno(fd, VIDIOC_G_CTRL, &c, "G_CTRL unknown id", EINVAL);
	set_ctrl(fd, V4L2_CID_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL);
	c.id = V4L2_CID_EXPOSURE_ABSOLUTE;
	c.value = 5000;
	expect_errno(fd, VIDIOC_S_CTRL, &c, "S_CTRL exposure 5000", ERANGE);
	c.id = V4L2_CID_EXPOSURE_AUTO;
	c.value = 0;
	expect_errno(fd, VIDIOC_S_CTRL, &c, "S_CTRL exposure auto = 0 (no menu item)", EINVAL);
	set_ctrl(fd, V4L2_CID_EXPOSURE_ABSOLUTE, 250);
	set_ctrl(fd, V4L2_CID_AUTO_WHITE_BALANCE, 0);
	set_ctrl(fd, V4L2_CID_WHITE_BALANCE_TEMPERATURE, 4600);
	set_ctrl(fd, V4L2_CID_FOCUS_AUTO, 0);
	set_ctrl(fd, V4L2_CID_FOCUS_ABSOLUTE, 7);       /* rounds to step 5 */
	set_ctrl(fd, V4L2_CID_FOCUS_ABSOLUTE, 0);
}

static int set_format(struct cam *c)
{
	struct v4l2_format f = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };
	struct v4l2_streamparm p = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };

	f.fmt.pix.width = 100;
	f.fmt.pix.height = 80;
	f.fmt.pix.pixelformat = v4l2_fourcc('H', '2', '6', '4');
	if (ioctl(c->fd, VIDIOC_TRY_FMT, &f) == 0)
		printf("  TRY_FMT H264 100x80 -> %s %ux%u\n", cc(f.fmt.pix.pixelformat),
		       f.fmt.pix.width, f.fmt.pix.height);
	else
		printf("  TRY_FMT H264 100x80 -> %s\n", strerror(errno));
	memset(&f.fmt, 0, sizeof f.fmt);
	f.fmt.pix.width = c->w;
	f.fmt.pix.height = c->h;
	f.fmt.pix.pixelformat = c->fourcc;
	if (xioctl(c->fd, VIDIOC_S_FMT, &f, "S_FMT") < 0)
		return -1;
	printf("  S_FMT -> %s %ux%u bpl %u sizeimage %u field %u colorspace %u\n",
	       cc(f.fmt.pix.pixelformat), f.fmt.pix.width, f.fmt.pix.height,
	       f.fmt.pix.bytesperline, f.fmt.pix.sizeimage, f.fmt.pix.field, f.fmt.pix.colorspace);
	c->fourcc = f.fmt.pix.pixelformat;
	c->w = f.fmt.pix.width;
	c->h = f.fmt.pix.height;
	p.parm.capture.timeperframe.numerator = 1;
	p.parm.capture.timeperframe.denominator = 15;
	if (xioctl(c->fd, VIDIOC_S_PARM, &p, "S_PARM") == 0)
		printf("  S_PARM 1/15 -> %u/%u cap %#x\n", p.parm.capture.timeperframe.numerator,
		       p.parm.capture.timeperframe.denominator, p.parm.capture.capability);
	return 0;
}

static int queue_all(struct cam *c)
{
	unsigned i;
	for (i = 0; i < c->nbufs; i++) {
		struct v4l2_buffer b = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE,
					 .memory = V4L2_MEMORY_MMAP, .index = i };
		if (xioctl(c->fd, VIDIOC_QBUF, &b, "QBUF") < 0)
			return -1;
	}
	return 0;
}

static int setup_buffers(struct cam *c)
{
	struct v4l2_requestbuffers rb = { .count = NBUF, .type = V4L2_BUF_TYPE_VIDEO_CAPTURE,
					  .memory = V4L2_MEMORY_MMAP };
	unsigned i;
	if (xioctl(c->fd, VIDIOC_REQBUFS, &rb, "REQBUFS") < 0)
		return -1;
	c->nbufs = rb.count;
	for (i = 0; i < rb.count; i++) {
		struct v4l2_buffer b = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE,
					 .memory = V4L2_MEMORY_MMAP, .index = i };
		if (xioctl(c->fd, VIDIOC_QUERYBUF, &b, "QUERYBUF") < 0)
			return -1;
		c->ptr[i] = mmap(NULL, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, c->fd, b.m.offset);
		if (c->ptr[i] == MAP_FAILED) {
			perror("  mmap");
			return -1;
		}
		c->len[i] = b.length;
		ioctl(c->fd, VIDIOC_QUERYBUF, &b);
		printf("  buffer %u offset %u length %u flags %#x\n", i, b.m.offset, b.length, b.flags);
	}
	return queue_all(c);
}

static void unmap_all(struct cam *c)
{
	unsigned i;
	for (i = 0; i < c->nbufs; i++)
		if (c->ptr[i] && c->ptr[i] != MAP_FAILED)
			munmap(c->ptr[i], c->len[i]);
	c->nbufs = 0;
}

static int stream(struct cam *c, int on)
{
	int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
	return xioctl(c->fd, on ? VIDIOC_STREAMON : VIDIOC_STREAMOFF, &type,
		      on ? "STREAMON" : "STREAMOFF");
}

static int count_ffc4(const unsigned char *p, size_t n)
{
	size_t i;
	int k = 0;
	for (i = 0; i + 1 < n; i++)
		k += p[i] == 0xFF && p[i + 1] == 0xC4;
	return k;
}

static void compare_expect(const unsigned char *p, size_t n)
{
	const char *path = getenv("PROBE_EXPECT");
	FILE *fp;
	unsigned char *want;
	size_t got;
	if (!path || !(fp = fopen(path, "rb")))
		return;
	want = malloc(n);
	got = fread(want, 1, n, fp);
	fclose(fp);
	printf("      %s bank file %s\n", got == n && !memcmp(want, p, n) ? "identical to" : "DIFFERS from", path);
	free(want);
}

static void dump(const unsigned char *p, size_t n)
{
	const char *path = getenv("PROBE_DUMP");
	FILE *fp;
	if (!path || !(fp = fopen(path, "wb")))
		return;
	fwrite(p, 1, n, fp);
	fclose(fp);
	unsetenv("PROBE_DUMP");
}

static void check_frame(struct cam *c, const struct v4l2_buffer *b)
{
	const unsigned char *p = c->ptr[b->index];
	double ts = b->timestamp.tv_sec * 1e3 + b->timestamp.tv_usec / 1e3;
	const char *keep = getenv("FAKECAM_KEEP_DHT");
	int ok;

	printf("    dq idx %u seq %u bytesused %u flags %#x dt %.1f ms", b->index, b->sequence,
	       b->bytesused, b->flags, c->last_ts ? ts - c->last_ts : 0.0);
	c->last_ts = ts;
	if (c->fourcc == V4L2_PIX_FMT_MJPEG) {
		int dht = count_ffc4(p, b->bytesused);
		int eoi = b->bytesused >= 2 && p[b->bytesused - 2] == 0xFF && p[b->bytesused - 1] == 0xD9;
		ok = p[0] == 0xFF && p[1] == 0xD8 && (dht == 0 || (keep && !strcmp(keep, "1"))) && eoi;
		printf(" SOI %s DHT %d EOI %s -> %s\n", p[0] == 0xFF && p[1] == 0xD8 ? "yes" : "NO",
		       dht, eoi ? "yes" : "no", ok ? "ok" : "BAD");
	} else {
		ok = b->bytesused == 2 * c->w * c->h && !(b->flags & V4L2_BUF_FLAG_ERROR);
		printf(" -> %s\n", ok ? "ok" : "BAD");
	}
	if (ok && c->fourcc == V4L2_PIX_FMT_YUYV)
		compare_expect(p, b->bytesused);
	if (ok)
		dump(p, b->bytesused);
	c->bad_frames += !ok;
}

/* Waits for a frame; every 3rd wait polls with a pipe too, every 4th uses select. */
static int wait_frame(struct cam *c, int k, short *revents)
{
	struct pollfd p[2] = { { .fd = c->fd, .events = POLLIN } };
	int pipefd[2], r;

	if (k % 4 == 3) {
		fd_set rs;
		struct timeval tv = { 1, 500000 };
		FD_ZERO(&rs);
		FD_SET(c->fd, &rs);
		r = select(c->fd + 1, &rs, NULL, NULL, &tv);
		*revents = r > 0 ? POLLIN : 0;
		return r;
	}
	if (k % 3 == 2 && pipe(pipefd) == 0) {
		p[1].fd = pipefd[0];
		p[1].events = POLLIN;
		r = poll(p, 2, 1500);
		close(pipefd[0]);
		close(pipefd[1]);
	} else {
		r = poll(p, 1, 1500);
	}
	*revents = p[0].revents;
	return r;
}

static enum outcome capture(struct cam *c, int frames)
{
	int k;
	for (k = 0; k < frames; k++) {
		struct v4l2_buffer b = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE, .memory = V4L2_MEMORY_MMAP };
		short rev = POLLIN;
		int r = getenv("PROBE_NOPOLL") ? 1 : wait_frame(c, k, &rev);
		if (r == 0) {
			printf("    wait timed out (stall?)\n");
			if (c->restarted++)
				return FAILED;
			printf("    restarting stream: STREAMOFF, QBUF all, STREAMON\n");
			if (stream(c, 0) || queue_all(c) || stream(c, 1))
				return FAILED;
			continue;
		}
		if (rev & (POLLERR | POLLHUP)) {
			printf("    poll revents %#x (POLLERR|POLLHUP = unplug)\n", rev);
			if (ioctl(c->fd, VIDIOC_DQBUF, &b) < 0)
				printf("    DQBUF -> %s\n", strerror(errno));
			return UNPLUGGED;
		}
		if (ioctl(c->fd, VIDIOC_DQBUF, &b) < 0) {
			printf("    DQBUF -> %s\n", strerror(errno));
			return errno == ENODEV ? UNPLUGGED : FAILED;
		}
		check_frame(c, &b);
		if (getenv("PROBE_AUTO") || k == 4)
			printf("    G_CTRL exposure %d wb %d\n", get_ctrl(c->fd, V4L2_CID_EXPOSURE_ABSOLUTE),
			       get_ctrl(c->fd, V4L2_CID_WHITE_BALANCE_TEMPERATURE));
		if (xioctl(c->fd, VIDIOC_QBUF, &b, "QBUF") < 0)
			return errno == ENODEV ? UNPLUGGED : FAILED;
	}
	return DONE;
}

static void misc_checks(int fd)
{
	char byte;
	int fd2 = open(dev_path, O_RDWR);
	printf("  second open -> %s\n", fd2 < 0 ? strerror(errno) : "ok (UNEXPECTED)");
	if (fd2 >= 0)
		close(fd2);
	printf("  read() -> %s\n", read(fd, &byte, 1) < 0 ? strerror(errno) : "ok (UNEXPECTED)");
}

static enum outcome session(struct cam *c, int frames, int full)
{
	struct v4l2_capability cap;
	enum outcome o;

	c->fd = open(dev_path, O_RDWR | O_CLOEXEC);
	if (c->fd < 0) {
		printf("open %s: %s\n", dev_path, strerror(errno));
		return FAILED;
	}
	if (xioctl(c->fd, VIDIOC_QUERYCAP, &cap, "QUERYCAP") < 0)
		return FAILED;
	printf("  driver '%s' card '%s' bus '%s' version %#x caps %#x device_caps %#x\n",
	       cap.driver, cap.card, cap.bus_info, cap.version, cap.capabilities, cap.device_caps);
	if (full) {
		misc_checks(c->fd);
		enum_formats(c->fd);
		enum_controls(c->fd);
		printf("  exposure (auto) now %d\n", get_ctrl(c->fd, V4L2_CID_EXPOSURE_ABSOLUTE));
		if (!getenv("PROBE_AUTO"))
			check_controls(c->fd);
	}
	if (set_format(c) < 0 || setup_buffers(c) < 0 || stream(c, 1) < 0) {
		close(c->fd);
		return FAILED;
	}
	o = capture(c, frames);
	if (o != UNPLUGGED)
		stream(c, 0);
	close(c->fd);
	unmap_all(c);
	return o;
}

static int reopen_wait(void)
{
	double t0 = now_ms();
	while (now_ms() - t0 < 5000) {
		int fd = open(dev_path, O_RDWR | O_CLOEXEC);
		if (fd >= 0) {
			close(fd);
			printf("  node back after %.0f ms\n", now_ms() - t0);
			return 0;
		}
		if (errno != ENOENT)
			printf("  reopen: %s\n", strerror(errno));
		usleep(50000);
	}
	printf("  node still gone after 5 s\n");
	return -1;
}

int main(int argc, char **argv)
{
	struct cam c = { .fourcc = V4L2_PIX_FMT_MJPEG, .w = 160, .h = 120 };
	int frames = argc > 4 ? atoi(argv[4]) : 10;
	enum outcome o;

	setvbuf(stdout, NULL, _IOLBF, 0);
	dev_path = getenv("FAKECAM_DEV") ? getenv("FAKECAM_DEV") : "/dev/video7";
	if (argc > 1)
		memcpy(&c.fourcc, argv[1], 4);
	if (argc > 3) {
		c.w = atoi(argv[2]);
		c.h = atoi(argv[3]);
	}
	printf("session 1: %s %ux%u, %d frames\n", cc(c.fourcc), c.w, c.h, frames);
	o = session(&c, frames, 1);
	if (o == UNPLUGGED) {
		printf("unplugged; closed, waiting for the node\n");
		unmap_all(&c);
		if (reopen_wait() == 0) {
			printf("session 2 (after replug): 3 frames\n");
			o = session(&c, 3, 0);
		}
	}
	printf("result: %s, bad frames %d\n", o == DONE ? "done" : o == UNPLUGGED ? "unplugged" : "failed",
	       c.bad_frames);
	return o == DONE ? 0 : 1;
}
