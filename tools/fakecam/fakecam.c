/*
 * fakecam.c - a UVC webcam emulated in user space, as an LD_PRELOAD shim.
 *
 * Build:
 *   cc -O2 -shared -fPIC -Wall -Wextra -o fakecam.so fakecam.c -ldl -lpthread
 * Use:
 *   FAKECAM_DEV=/dev/video7 FAKECAM_BANK=/path/to/bank LD_PRELOAD=./fakecam.so prog
 *
 * What it emulates
 *   A V4L2 capture node driven by uvcvideo ("cac fake UVC camera"): MJPG and
 *   YUYV formats, the discrete frame sizes of a frame bank, 30 and 15 fps,
 *   six camera controls (auto/manual exposure, white balance, focus), MMAP
 *   streaming (REQBUFS/QUERYBUF/QBUF/DQBUF/STREAMON/STREAMOFF) and poll().
 *   open() of FAKECAM_DEV returns a memfd; the buffers live in that memfd, so
 *   mmap() of the fd with a QUERYBUF offset maps the real buffer pages.  A
 *   sensor thread started at STREAMON fills the oldest queued buffer every
 *   frame interval with the bank frame nearest to the current rig pose.
 *   Every other path and fd passes through to libc untouched.
 *
 * Environment
 *   FAKECAM_DEV      device path to emulate, e.g. /dev/video7.  Unset: the
 *                    shim does nothing.
 *   FAKECAM_BANK     bank folder.  BANK/index.txt holds a header line
 *                    "rev <table_steps_per_rev>", then one line per frame:
 *                    "<table_step> <rail_step> <width> <height> <jpeg> <yuyv>"
 *                    (file names relative to BANK; blank lines and lines
 *                    starting with '#' are skipped).  The .yuyv file is
 *                    packed YUYV, exactly width*2*height bytes.  The bank is
 *                    (re)read at every open(); open() fails with ENOENT and
 *                    a message on stderr when it cannot be read.
 *   FAKECAM_POSE     file holding "<table_phys_steps> <rail_phys_steps>\n",
 *                    rewritten concurrently by another process; read at every
 *                    frame.  Unset: pose (0,0).  Unparsable: retried 5 times
 *                    1 ms apart, then the last good pose is used.
 *   FAKECAM_FORMATS  offered formats in order, e.g. "YUYV" or "MJPG,YUYV"
 *                    (default "MJPG,YUYV").
 *   FAKECAM_KEEP_DHT =1: serve MJPEG frames with their DHT segments (by
 *                    default all DHT segments are stripped, as UVC cameras do).
 *   FAKECAM_LOG      append one line per event to this file.
 *   FAKECAM_FAULTS   comma-separated faults, see below.
 *
 * Faults (N counts frames filled since the shim loaded, from 0, across opens)
 *   stall@N        from frame N on no buffer is filled until STREAMOFF/close.
 *   corrupt@N      frame N is corrupt (MJPG: entropy data after SOS replaced
 *                  by garbage and cut to half, no EOI; YUYV: bytesused is
 *                  half the image and V4L2_BUF_FLAG_ERROR is set).
 *   unplug@N[:MS]  when frame N would be filled the device vanishes: ioctl and
 *                  mmap give ENODEV, poll gives POLLERR|POLLHUP, waiting
 *                  DQBUFs wake with ENODEV; open() gives ENOENT for MS ms
 *                  (forever without :MS), then the camera is back with default
 *                  settings.  close() still works.
 *   ignore-rate    S_PARM claims the asked interval, the clock stays at 1/30.
 *   sfmt-einval    S_FMT/TRY_FMT give EINVAL for a size or fourcc not offered.
 *   stall, corrupt and unplug fire once each.
 *
 * Log lines: open, close, s_fmt <fourcc> <w>x<h>, s_parm <num>/<den>,
 *   s_ctrl <id hex> <value> (successful sets), streamon, streamoff,
 *   frame <seq> <table_phys> <rail_phys> <table_step> <rail_step> <fourcc>
 *   <bytesused> <ok|corrupt|readerr>, dqbuf <index> <seq>, fault <what>.
 *
 * Limits: one open instance (a second open gives EBUSY); dup()ed fds, epoll
 * and read() streaming are not emulated; an fd left open across an unplug
 * becomes a dead fd (ENODEV) and does not block the replugged camera.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <sys/select.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <time.h>
#include <unistd.h>

enum { MAX_BUFS = 8, MIN_BUFS = 2, MAX_FAULTS = 16, MAX_SIZES = 64, MAX_DEAD = 8,
       MAX_FMTS = 2, NCTRLS = 6, POSE_TRIES = 5 };

enum buf_state { BUF_DEQUEUED, BUF_QUEUED, BUF_DONE };
enum fault_kind { F_STALL, F_CORRUPT, F_UNPLUG, F_IGNORE_RATE, F_SFMT_EINVAL };
enum fill_result { FILL_OK, FILL_CORRUPT, FILL_READERR };

struct fc_fault { enum fault_kind kind; long n; long ms; int fired; };
struct fc_frame { int table, rail; unsigned w, h; char *jpeg, *yuyv; };
struct fc_size { unsigned w, h; size_t max_jpeg; };
struct fc_buf {
	enum buf_state state;
	unsigned long order;            /* queue / done order */
	uint32_t bytesused, flags, sequence;
	struct timeval ts;
	void *map_addr;                 /* client mapping, for the MAPPED flag */
};

struct fc_real {
	int (*open)(const char *, int, ...);
	int (*open64)(const char *, int, ...);
	int (*openat)(int, const char *, int, ...);
	int (*openat64)(int, const char *, int, ...);
	int (*close)(int);
	int (*ioctl)(int, unsigned long, ...);
	void *(*mmap)(void *, size_t, int, int, int, off_t);
	void *(*mmap64)(void *, size_t, int, int, int, off64_t);
	int (*munmap)(void *, size_t);
	int (*poll)(struct pollfd *, nfds_t, int);
	int (*ppoll)(struct pollfd *, nfds_t, const struct timespec *, const sigset_t *);
	int (*select)(int, fd_set *, fd_set *, fd_set *, struct timeval *);
	ssize_t (*read)(int, void *, size_t);
};

/* The one device: configuration, bank, settings, open instance, stream. */
struct fakecam {
	pthread_once_t once;
	pthread_mutex_t mu;
	pthread_cond_t cv;              /* CLOCK_MONOTONIC; any state change */
	struct fc_real real;
	/* configuration from the environment */
	const char *dev_path, *bank_dir, *pose_path, *log_path;
	int keep_dht, log_fd;
	uint32_t fmts[MAX_FMTS];
	int nfmts;
	struct fc_fault faults[MAX_FAULTS];
	int nfaults;
	/* bank */
	int rev, nframes, nsizes;
	struct fc_frame *frames;
	struct fc_size sizes[MAX_SIZES];
	/* settings, kept across opens until an unplug */
	int configured;
	uint32_t fourcc;
	unsigned w, h, parm_num, parm_den;
	int ctrl[NCTRLS];
	/* open instance */
	int fd, unplugged, dead[MAX_DEAD];
	unsigned gen;
	long long unplug_until;         /* 0: plugged, -1: forever, else ns */
	/* buffers */
	unsigned nbufs;
	size_t stride;
	unsigned char *mem;             /* the shim's own view of the memfd */
	struct fc_buf bufs[MAX_BUFS];
	unsigned long order_ctr;
	/* stream */
	int streaming, stalled, clock_run, have_thread;
	pthread_t thread;
	uint32_t seq;                   /* next sensor sequence number */
	long frames_filled;
	int pose_t, pose_r;             /* last good pose */
};

static struct fakecam dev = {
	.once = PTHREAD_ONCE_INIT,
	.mu = PTHREAD_MUTEX_INITIALIZER,
	.fd = -1, .log_fd = -1,
	.dead = { -1, -1, -1, -1, -1, -1, -1, -1 },
};

/* ---------------------------------------------------------------- basics */

static long long now_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static struct timespec ns_to_ts(long long ns)
{
	struct timespec ts = { ns / 1000000000LL, ns % 1000000000LL };
	return ts;
}

/* Wait on the condvar until the absolute monotonic deadline (-1: forever). */
static void wait_until(long long deadline)
{
	if (deadline < 0) {
		pthread_cond_wait(&dev.cv, &dev.mu);
	} else {
		struct timespec ts = ns_to_ts(deadline);
		pthread_cond_timedwait(&dev.cv, &dev.mu, &ts);
	}
}

static void lock(void) { pthread_mutex_lock(&dev.mu); }
static void unlock(void) { pthread_mutex_unlock(&dev.mu); }

static int fail(int err) { errno = err; return -1; }

/* sin() without libm (the build line does not link -lm). */
static double fc_sin(double x)
{
	const double pi = 3.14159265358979323846;
	long k = (long)(x / (2 * pi));
	double x2, t, s;
	int i;

	x -= k * 2 * pi;
	if (x > pi) x -= 2 * pi;
	if (x < -pi) x += 2 * pi;
	x2 = x * x;
	t = x;
	s = x;
	for (i = 1; i < 12; i++) {
		t *= -x2 / ((2 * i) * (2 * i + 1));
		s += t;
	}
	return s;
}

static void fourcc_str(uint32_t f, char out[5])
{
	out[0] = f & 0xff; out[1] = (f >> 8) & 0xff;
	out[2] = (f >> 16) & 0xff; out[3] = (f >> 24) & 0xff; out[4] = 0;
}

static void log_line(const char *fmt, ...)
{
	char line[256];
	va_list ap;
	int n;

	if (!dev.log_path)
		return;
	if (dev.log_fd < 0)
		dev.log_fd = dev.real.open(dev.log_path,
					   O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
	if (dev.log_fd < 0)
		return;
	va_start(ap, fmt);
	n = vsnprintf(line, sizeof line - 1, fmt, ap);
	va_end(ap);
	if (n < 0)
		return;
	if (n > (int)sizeof line - 2)
		n = sizeof line - 2;
	line[n++] = '\n';
	if (write(dev.log_fd, line, n) < 0)
		return;
}

/* ----------------------------------------------------------- configuration */

static void parse_formats(const char *s)
{
	char buf[64], *tok, *save = NULL;

	dev.nfmts = 0;
	if (s && *s) {
		snprintf(buf, sizeof buf, "%s", s);
		for (tok = strtok_r(buf, ", ", &save); tok && dev.nfmts < MAX_FMTS;
		     tok = strtok_r(NULL, ", ", &save)) {
			uint32_t f = 0;
			if (!strcmp(tok, "MJPG")) f = V4L2_PIX_FMT_MJPEG;
			else if (!strcmp(tok, "YUYV")) f = V4L2_PIX_FMT_YUYV;
			else fprintf(stderr, "fakecam: unknown format '%s' ignored\n", tok);
			if (f && (dev.nfmts == 0 || dev.fmts[0] != f))
				dev.fmts[dev.nfmts++] = f;
		}
	}
	if (dev.nfmts == 0) {
		dev.fmts[0] = V4L2_PIX_FMT_MJPEG;
		dev.fmts[1] = V4L2_PIX_FMT_YUYV;
		dev.nfmts = 2;
	}
}

static void parse_fault(const char *tok)
{
	struct fc_fault f = { 0, 0, 0, 0 };
	const char *at = strchr(tok, '@');
	char *end;

	if (!strcmp(tok, "ignore-rate")) f.kind = F_IGNORE_RATE;
	else if (!strcmp(tok, "sfmt-einval")) f.kind = F_SFMT_EINVAL;
	else if (at && !strncmp(tok, "stall@", 6)) f.kind = F_STALL;
	else if (at && !strncmp(tok, "corrupt@", 8)) f.kind = F_CORRUPT;
	else if (at && !strncmp(tok, "unplug@", 7)) f.kind = F_UNPLUG;
	else goto bad;
	if (at) {
		f.n = strtol(at + 1, &end, 10);
		if (end == at + 1 || f.n < 0) goto bad;
		if (f.kind == F_UNPLUG && *end == ':') {
			const char *ms = end + 1;
			f.ms = strtol(ms, &end, 10);
			if (end == ms || f.ms < 0) goto bad;
		}
		if (*end) goto bad;
	}
	if (dev.nfaults < MAX_FAULTS)
		dev.faults[dev.nfaults++] = f;
	return;
bad:
	fprintf(stderr, "fakecam: bad fault '%s' ignored\n", tok);
}

static void parse_faults(const char *s)
{
	char buf[512], *tok, *save = NULL;

	if (!s)
		return;
	snprintf(buf, sizeof buf, "%s", s);
	for (tok = strtok_r(buf, ", ", &save); tok; tok = strtok_r(NULL, ", ", &save))
		parse_fault(tok);
}

static int has_fault(enum fault_kind k)
{
	int i;
	for (i = 0; i < dev.nfaults; i++)
		if (dev.faults[i].kind == k)
			return 1;
	return 0;
}

/* Fires (once) a frame-counted fault of kind k at frame n; returns it. */
static struct fc_fault *fire_fault(enum fault_kind k, long n)
{
	int i;
	for (i = 0; i < dev.nfaults; i++) {
		struct fc_fault *f = &dev.faults[i];
		if (f->kind == k && !f->fired && f->n == n) {
			f->fired = 1;
			return f;
		}
	}
	return NULL;
}

static void *sym(const char *name)
{
	void *p = dlsym(RTLD_NEXT, name);
	if (!p)
		fprintf(stderr, "fakecam: dlsym(%s) failed\n", name);
	return p;
}

static void init_once(void)
{
	pthread_condattr_t ca;
	const char *keep;

	dev.real.open = sym("open");
	dev.real.open64 = sym("open64");
	dev.real.openat = sym("openat");
	dev.real.openat64 = sym("openat64");
	dev.real.close = sym("close");
	dev.real.ioctl = sym("ioctl");
	dev.real.mmap = sym("mmap");
	dev.real.mmap64 = sym("mmap64");
	dev.real.munmap = sym("munmap");
	dev.real.poll = sym("poll");
	dev.real.ppoll = sym("ppoll");
	dev.real.select = sym("select");
	dev.real.read = sym("read");

	pthread_condattr_init(&ca);
	pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
	pthread_cond_init(&dev.cv, &ca);
	pthread_condattr_destroy(&ca);

	dev.dev_path = getenv("FAKECAM_DEV");
	if (dev.dev_path && !*dev.dev_path)
		dev.dev_path = NULL;
	dev.bank_dir = getenv("FAKECAM_BANK");
	dev.pose_path = getenv("FAKECAM_POSE");
	dev.log_path = getenv("FAKECAM_LOG");
	keep = getenv("FAKECAM_KEEP_DHT");
	dev.keep_dht = keep && !strcmp(keep, "1");
	parse_formats(getenv("FAKECAM_FORMATS"));
	parse_faults(getenv("FAKECAM_FAULTS"));
}

static void fc_init(void) { pthread_once(&dev.once, init_once); }

__attribute__((constructor)) static void fc_ctor(void) { fc_init(); }

/* ------------------------------------------------------------------ fds */

static int is_dead_fd(int fd)
{
	int i;
	for (i = 0; i < MAX_DEAD; i++)
		if (fd >= 0 && __atomic_load_n(&dev.dead[i], __ATOMIC_ACQUIRE) == fd)
			return 1;
	return 0;
}

static int is_fake_fd(int fd)
{
	return fd >= 0 && (__atomic_load_n(&dev.fd, __ATOMIC_ACQUIRE) == fd || is_dead_fd(fd));
}

static int is_fake_path(const char *path)
{
	fc_init();
	return dev.dev_path && !strcmp(path, dev.dev_path);
}

/* ----------------------------------------------------------------- bank */

static void bank_free(void)
{
	int i;
	for (i = 0; i < dev.nframes; i++) {
		free(dev.frames[i].jpeg);
		free(dev.frames[i].yuyv);
	}
	free(dev.frames);
	dev.frames = NULL;
	dev.nframes = dev.nsizes = 0;
}

static char *bank_path(const char *name)
{
	size_t n = strlen(dev.bank_dir) + strlen(name) + 2;
	char *p = malloc(n);
	if (p)
		snprintf(p, n, "%s/%s", dev.bank_dir, name);
	return p;
}

static int bank_error(const char *what, const char *file)
{
	fprintf(stderr, "fakecam: bank: %s: %s\n", what, file);
	bank_free();
	return -1;
}

static struct fc_size *size_find(unsigned w, unsigned h)
{
	int i;
	for (i = 0; i < dev.nsizes; i++)
		if (dev.sizes[i].w == w && dev.sizes[i].h == h)
			return &dev.sizes[i];
	return NULL;
}

/* Checks a frame's files and records its size; 0 or -1 (message printed). */
static int bank_add_frame(struct fc_frame *f)
{
	struct stat st;
	struct fc_size *s;

	if (stat(f->jpeg, &st) < 0 || !S_ISREG(st.st_mode))
		return bank_error("cannot read JPEG", f->jpeg);
	s = size_find(f->w, f->h);
	if (!s) {
		if (dev.nsizes == MAX_SIZES)
			return bank_error("too many frame sizes", f->jpeg);
		s = &dev.sizes[dev.nsizes++];
		s->w = f->w; s->h = f->h; s->max_jpeg = 0;
	}
	if ((size_t)st.st_size > s->max_jpeg)
		s->max_jpeg = st.st_size;
	if (stat(f->yuyv, &st) < 0 || !S_ISREG(st.st_mode))
		return bank_error("cannot read YUYV", f->yuyv);
	if ((size_t)st.st_size != (size_t)f->w * 2 * f->h)
		return bank_error("YUYV file is not width*2*height bytes", f->yuyv);
	return 0;
}

static int bank_parse_line(const char *line, const char *index)
{
	char jpeg[PATH_MAX / 2], yuyv[PATH_MAX / 2];
	struct fc_frame f;
	void *grown;

	if (sscanf(line, "%d %d %u %u %2047s %2047s", &f.table, &f.rail, &f.w, &f.h,
		   jpeg, yuyv) != 6 || !f.w || !f.h || (f.w & 1))
		return bank_error("bad frame line in", index);
	grown = realloc(dev.frames, (dev.nframes + 1) * sizeof *dev.frames);
	if (!grown)
		return bank_error("out of memory reading", index);
	dev.frames = grown;
	f.jpeg = bank_path(jpeg);
	f.yuyv = bank_path(yuyv);
	dev.frames[dev.nframes++] = f;
	if (!f.jpeg || !f.yuyv)
		return bank_error("out of memory reading", index);
	return bank_add_frame(&dev.frames[dev.nframes - 1]);
}

/* Loads BANK/index.txt; 0, or -1 with a message on stderr. */
static int bank_load(void)
{
	char *index, line[PATH_MAX * 2];
	int have_rev = 0, rc = 0;
	FILE *fp;

	bank_free();
	if (!dev.bank_dir)
		return bank_error("FAKECAM_BANK is not set", "(none)");
	index = bank_path("index.txt");
	if (!index)
		return -1;
	fp = fopen(index, "re");
	if (!fp) {
		bank_error("cannot read", index);
		free(index);
		return -1;
	}
	while (rc == 0 && fgets(line, sizeof line, fp)) {
		const char *p = line + strspn(line, " \t");
		if (*p == '\n' || *p == 0 || *p == '#')
			continue;
		if (!have_rev) {
			if (sscanf(p, "rev %d", &dev.rev) != 1 || dev.rev <= 0)
				rc = bank_error("first line must be 'rev <steps>' in", index);
			have_rev = 1;
			continue;
		}
		rc = bank_parse_line(p, index);
	}
	fclose(fp);
	if (rc == 0 && dev.nframes == 0)
		rc = bank_error("no frames in", index);
	free(index);
	return rc;
}

static int mod_pos(int a, int m) { int r = a % m; return r < 0 ? r + m : r; }

/* The bank frame for a pose at the negotiated size (exact, else nearest). */
static const struct fc_frame *bank_pick(int table, int rail)
{
	const struct fc_frame *best = NULL;
	long best_d = 0;
	int t = mod_pos(table, dev.rev), i;

	for (i = 0; i < dev.nframes; i++) {
		const struct fc_frame *f = &dev.frames[i];
		int dt;
		long d;
		if (f->w != dev.w || f->h != dev.h)
			continue;
		dt = abs(mod_pos(f->table, dev.rev) - t);
		if (dev.rev - dt < dt)
			dt = dev.rev - dt;
		d = (long)dt + labs((long)f->rail - rail);
		if (!best || d < best_d) {
			best = f;
			best_d = d;
		}
	}
	return best;
}

/* ----------------------------------------------------------------- pose */

static int read_small_file(const char *path, char *buf, size_t cap)
{
	int fd = dev.real.open(path, O_RDONLY | O_CLOEXEC);
	ssize_t n;
	if (fd < 0)
		return -1;
	n = dev.real.read(fd, buf, cap - 1);
	dev.real.close(fd);
	if (n < 0)
		return -1;
	buf[n] = 0;
	return 0;
}

/* "<int> <int>" then blanks; strict also wants the newline. */
static int parse_pose(const char *s, int strict, int *t, int *r)
{
	char *end;
	long a, b;
	int nl = 0;

	a = strtol(s, &end, 10);
	if (end == s)
		return -1;
	s = end;
	b = strtol(s, &end, 10);
	if (end == s)
		return -1;
	for (; *end; end++) {
		if (*end == '\n') nl = 1;
		else if (*end != ' ' && *end != '\t' && *end != '\r') return -1;
	}
	if (strict && !nl)
		return -1;
	*t = (int)a;
	*r = (int)b;
	return 0;
}

static void read_pose(int *t, int *r)
{
	char buf[128];
	int i, ok = 0;

	if (!dev.pose_path) {
		*t = *r = 0;
		return;
	}
	buf[0] = 0;
	for (i = 0; i < POSE_TRIES && !ok; i++) {
		if (i)
			usleep(1000);
		ok = read_small_file(dev.pose_path, buf, sizeof buf) == 0 &&
		     parse_pose(buf, 1, t, r) == 0;
	}
	if (!ok)
		ok = parse_pose(buf, 0, t, r) == 0;
	if (ok) {
		dev.pose_t = *t;
		dev.pose_r = *r;
	}
	*t = dev.pose_t;
	*r = dev.pose_r;
}

/* ------------------------------------------------------------- controls */

struct fc_ctrl {
	uint32_t id, type;
	const char *name;
	int min, max, step, def;
	int lock_idx, manual_value;     /* inactive unless ctrl[lock_idx]==manual */
};

enum { C_AWB, C_WB_TEMP, C_EXP_AUTO, C_EXP_ABS, C_FOCUS_ABS, C_FOCUS_AUTO };

/* In id order, for V4L2_CTRL_FLAG_NEXT_CTRL. */
static const struct fc_ctrl ctrls[NCTRLS] = {
	[C_AWB] = { V4L2_CID_AUTO_WHITE_BALANCE, V4L2_CTRL_TYPE_BOOLEAN,
		    "White Balance, Automatic", 0, 1, 1, 1, -1, 0 },
	[C_WB_TEMP] = { V4L2_CID_WHITE_BALANCE_TEMPERATURE, V4L2_CTRL_TYPE_INTEGER,
			"White Balance Temperature", 2800, 6500, 10, 4600, C_AWB, 0 },
	[C_EXP_AUTO] = { V4L2_CID_EXPOSURE_AUTO, V4L2_CTRL_TYPE_MENU,
			 "Auto Exposure", 0, 3, 1, 3, -1, 0 },
	[C_EXP_ABS] = { V4L2_CID_EXPOSURE_ABSOLUTE, V4L2_CTRL_TYPE_INTEGER,
			"Exposure Time, Absolute", 3, 2047, 1, 250, C_EXP_AUTO, 1 },
	[C_FOCUS_ABS] = { V4L2_CID_FOCUS_ABSOLUTE, V4L2_CTRL_TYPE_INTEGER,
			  "Focus, Absolute", 0, 250, 5, 0, C_FOCUS_AUTO, 0 },
	[C_FOCUS_AUTO] = { V4L2_CID_FOCUS_AUTO, V4L2_CTRL_TYPE_BOOLEAN,
			   "Focus, Automatic Continuous", 0, 1, 1, 1, -1, 0 },
};

static int ctrl_index(uint32_t id)
{
	int i;
	for (i = 0; i < NCTRLS; i++)
		if (ctrls[i].id == id)
			return i;
	return -1;
}

static int ctrl_inactive(int i)
{
	int l = ctrls[i].lock_idx;
	return l >= 0 && dev.ctrl[l] != ctrls[i].manual_value;
}

static int drift_exposure(uint32_t seq) { return (int)(250.0 + 60.0 * fc_sin(seq * 0.7) + 0.5); }
static int drift_wb_temp(uint32_t seq) { return (int)(4600.0 + 300.0 * fc_sin(seq * 0.5) + 0.5); }

/* Current value; the auto-driven ones follow the sensor at sequence seq. */
static int ctrl_value_at(int i, uint32_t seq)
{
	if (i == C_EXP_ABS && ctrl_inactive(i))
		return drift_exposure(seq);
	if (i == C_WB_TEMP && ctrl_inactive(i))
		return drift_wb_temp(seq);
	return dev.ctrl[i];
}

static uint32_t last_seq(void) { return dev.seq ? dev.seq - 1 : 0; }

static void ctrl_defaults(void)
{
	int i;
	for (i = 0; i < NCTRLS; i++)
		dev.ctrl[i] = ctrls[i].def;
}

/* Validates and rounds v for control i (no side effects). */
static int ctrl_check(int i, int *v)
{
	const struct fc_ctrl *c = &ctrls[i];
	if (*v < c->min || *v > c->max)
		return ERANGE;
	if (i == C_EXP_AUTO && *v != V4L2_EXPOSURE_MANUAL && *v != V4L2_EXPOSURE_APERTURE_PRIORITY)
		return EINVAL;
	if (ctrl_inactive(i))
		return EACCES;
	*v = c->min + (int)(((long)*v - c->min + c->step / 2) / c->step) * c->step;
	if (*v > c->max)
		*v -= c->step;
	return 0;
}

/* Sets control i; switching an auto control off freezes its dependants. */
static int ctrl_set(int i, int *v)
{
	int err = ctrl_check(i, v), j;
	if (err)
		return err;
	for (j = 0; j < NCTRLS; j++)
		if (ctrls[j].lock_idx == i && ctrl_inactive(j) && *v == ctrls[j].manual_value)
			dev.ctrl[j] = ctrl_value_at(j, last_seq());
	dev.ctrl[i] = *v;
	log_line("s_ctrl 0x%x %d", ctrls[i].id, *v);
	return 0;
}

static int do_queryctrl(struct v4l2_queryctrl *q)
{
	uint32_t id = q->id & ~(V4L2_CTRL_FLAG_NEXT_CTRL | V4L2_CTRL_FLAG_NEXT_COMPOUND);
	int i = -1, k;
	const struct fc_ctrl *c;

	if (q->id & V4L2_CTRL_FLAG_NEXT_CTRL) {
		for (k = 0; k < NCTRLS && i < 0; k++)
			if (ctrls[k].id > id)
				i = k;
	} else {
		i = ctrl_index(id);
	}
	if (i < 0)
		return EINVAL;
	c = &ctrls[i];
	memset(q, 0, sizeof *q);
	q->id = c->id;
	q->type = c->type;
	snprintf((char *)q->name, sizeof q->name, "%s", c->name);
	q->minimum = c->min;
	q->maximum = c->max;
	q->step = c->step;
	q->default_value = c->def;
	if (ctrl_inactive(i))
		q->flags |= V4L2_CTRL_FLAG_INACTIVE;
	if (c->lock_idx < 0)
		q->flags |= V4L2_CTRL_FLAG_UPDATE;
	return 0;
}

static int do_querymenu(struct v4l2_querymenu *m)
{
	const char *name = NULL;
	if (m->id != V4L2_CID_EXPOSURE_AUTO)
		return EINVAL;
	if (m->index == V4L2_EXPOSURE_MANUAL) name = "Manual Mode";
	if (m->index == V4L2_EXPOSURE_APERTURE_PRIORITY) name = "Aperture Priority Mode";
	if (!name)
		return EINVAL;
	memset(m->name, 0, sizeof m->name);
	snprintf((char *)m->name, sizeof m->name, "%s", name);
	m->reserved = 0;
	return 0;
}

static int do_g_ctrl(struct v4l2_control *c)
{
	int i = ctrl_index(c->id);
	if (i < 0)
		return EINVAL;
	c->value = ctrl_value_at(i, last_seq());
	return 0;
}

static int do_s_ctrl(struct v4l2_control *c)
{
	int i = ctrl_index(c->id);
	if (i < 0)
		return EINVAL;
	return ctrl_set(i, &c->value);
}

static int do_ext_ctrls(unsigned long req, struct v4l2_ext_controls *e)
{
	uint32_t k;
	for (k = 0; k < e->count; k++) {
		struct v4l2_ext_control *x = &e->controls[k];
		int i = ctrl_index(x->id), err = 0, v;
		if (i < 0) {
			err = EINVAL;
		} else if (req == VIDIOC_G_EXT_CTRLS) {
			x->value = ctrl_value_at(i, last_seq());
		} else {
			v = x->value;
			err = req == VIDIOC_S_EXT_CTRLS ? ctrl_set(i, &v) : ctrl_check(i, &v);
			if (!err)
				x->value = v;
		}
		if (err) {
			e->error_idx = k;
			return err;
		}
	}
	return 0;
}

/* -------------------------------------------------------------- formats */

static int fmt_offered(uint32_t f)
{
	int i;
	for (i = 0; i < dev.nfmts; i++)
		if (dev.fmts[i] == f)
			return 1;
	return 0;
}

static size_t page_round(size_t n)
{
	size_t pg = (size_t)sysconf(_SC_PAGESIZE);
	return (n + pg - 1) / pg * pg;
}

static uint32_t fmt_sizeimage(uint32_t fourcc, unsigned w, unsigned h)
{
	const struct fc_size *s = size_find(w, h);
	if (fourcc == V4L2_PIX_FMT_YUYV)
		return w * 2 * h;
	return (uint32_t)(page_round(s ? s->max_jpeg : (size_t)w * h) + 65536);
}

static void fill_pix(struct v4l2_pix_format *p, uint32_t fourcc, unsigned w, unsigned h)
{
	memset(p, 0, sizeof *p);
	p->width = w;
	p->height = h;
	p->pixelformat = fourcc;
	p->field = V4L2_FIELD_NONE;
	p->bytesperline = fourcc == V4L2_PIX_FMT_YUYV ? 2 * w : 0;
	p->sizeimage = fmt_sizeimage(fourcc, w, h);
	p->colorspace = V4L2_COLORSPACE_SRGB;
}

/* uvcvideo's choice: the size whose area differs least (overlap-based). */
static const struct fc_size *nearest_size(unsigned w, unsigned h)
{
	const struct fc_size *best = NULL;
	unsigned long long best_d = 0;
	int i;
	for (i = 0; i < dev.nsizes; i++) {
		const struct fc_size *s = &dev.sizes[i];
		unsigned long long ov = (unsigned long long)(s->w < w ? s->w : w) * (s->h < h ? s->h : h);
		unsigned long long d = (unsigned long long)s->w * s->h + (unsigned long long)w * h - 2 * ov;
		if (!best || d < best_d) {
			best = s;
			best_d = d;
		}
	}
	return best;
}

static int try_fmt(struct v4l2_format *f)
{
	struct v4l2_pix_format *p = &f->fmt.pix;
	uint32_t fourcc = p->pixelformat;
	const struct fc_size *s;

	if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
		return EINVAL;
	if (has_fault(F_SFMT_EINVAL) && (!fmt_offered(fourcc) || !size_find(p->width, p->height))) {
		log_line("fault sfmt-einval");
		return EINVAL;
	}
	if (!fmt_offered(fourcc))
		fourcc = dev.fmts[0];
	s = nearest_size(p->width, p->height);
	fill_pix(p, fourcc, s->w, s->h);
	return 0;
}

static int do_s_fmt(struct v4l2_format *f)
{
	char cc[5];
	int err;
	if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
		return EINVAL;
	if (dev.nbufs)
		return EBUSY;
	err = try_fmt(f);
	if (err)
		return err;
	dev.fourcc = f->fmt.pix.pixelformat;
	dev.w = f->fmt.pix.width;
	dev.h = f->fmt.pix.height;
	fourcc_str(dev.fourcc, cc);
	log_line("s_fmt %s %ux%u", cc, dev.w, dev.h);
	return 0;
}

static int do_g_fmt(struct v4l2_format *f)
{
	if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
		return EINVAL;
	fill_pix(&f->fmt.pix, dev.fourcc, dev.w, dev.h);
	return 0;
}

static int do_enum_fmt(struct v4l2_fmtdesc *d)
{
	uint32_t idx = d->index, type = d->type;
	if (type != V4L2_BUF_TYPE_VIDEO_CAPTURE || idx >= (uint32_t)dev.nfmts)
		return EINVAL;
	memset(d, 0, sizeof *d);
	d->index = idx;
	d->type = type;
	d->pixelformat = dev.fmts[idx];
	if (d->pixelformat == V4L2_PIX_FMT_MJPEG) {
		d->flags = V4L2_FMT_FLAG_COMPRESSED;
		snprintf((char *)d->description, sizeof d->description, "Motion-JPEG");
	} else {
		snprintf((char *)d->description, sizeof d->description, "YUYV 4:2:2");
	}
	return 0;
}

static int do_enum_framesizes(struct v4l2_frmsizeenum *e)
{
	if (!fmt_offered(e->pixel_format) || e->index >= (uint32_t)dev.nsizes)
		return EINVAL;
	e->type = V4L2_FRMSIZE_TYPE_DISCRETE;
	e->discrete.width = dev.sizes[e->index].w;
	e->discrete.height = dev.sizes[e->index].h;
	return 0;
}

static const unsigned rates[2] = { 30, 15 };    /* intervals 1/30, 1/15 */

static int do_enum_frameintervals(struct v4l2_frmivalenum *e)
{
	if (!fmt_offered(e->pixel_format) || !size_find(e->width, e->height) || e->index >= 2)
		return EINVAL;
	e->type = V4L2_FRMIVAL_TYPE_DISCRETE;
	e->discrete.numerator = 1;
	e->discrete.denominator = rates[e->index];
	return 0;
}

static void fill_parm(struct v4l2_streamparm *p)
{
	memset(&p->parm, 0, sizeof p->parm);
	p->parm.capture.capability = V4L2_CAP_TIMEPERFRAME;
	p->parm.capture.timeperframe.numerator = dev.parm_num;
	p->parm.capture.timeperframe.denominator = dev.parm_den;
}

static int do_g_parm(struct v4l2_streamparm *p)
{
	if (p->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
		return EINVAL;
	fill_parm(p);
	return 0;
}

static int do_s_parm(struct v4l2_streamparm *p)
{
	struct v4l2_fract *t = &p->parm.capture.timeperframe;
	unsigned num = t->numerator, den = t->denominator;

	if (p->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
		return EINVAL;
	if (dev.streaming)
		return EBUSY;
	if (has_fault(F_IGNORE_RATE) && num && den) {
		if ((unsigned long long)num * 30 != den)
			log_line("fault ignore-rate");
	} else {
		/* nearest of 1/30 and 1/15: compare num/den with 1/20 */
		int slow = den && (unsigned long long)num * 20 >= den;
		num = 1;
		den = slow ? 15 : 30;
	}
	dev.parm_num = num;
	dev.parm_den = den;
	fill_parm(p);
	log_line("s_parm %u/%u", num, den);
	return 0;
}

static long long frame_interval_ns(void)
{
	if (has_fault(F_IGNORE_RATE) || !dev.parm_den)
		return 1000000000LL / 30;
	return 1000000000LL * dev.parm_num / dev.parm_den;
}

/* Default settings at first open and after a replug; keeps valid ones. */
static void settings_validate(void)
{
	if (!dev.configured) {
		ctrl_defaults();
		dev.parm_num = 1;
		dev.parm_den = 30;
		dev.configured = 1;
		dev.fourcc = 0;
	}
	if (!fmt_offered(dev.fourcc) || !size_find(dev.w, dev.h)) {
		dev.fourcc = dev.fmts[0];
		dev.w = dev.sizes[0].w;
		dev.h = dev.sizes[0].h;
	}
}

/* ---------------------------------------------------------------- JPEG */

/* Offset just past the SOS header, or 0 when there is none. */
static size_t jpeg_scan_start(const unsigned char *p, size_t n)
{
	size_t r = 2;
	while (r + 4 <= n && p[r] == 0xFF) {
		unsigned m = p[r + 1];
		size_t len;
		if (m == 0xFF) { r++; continue; }
		if (m == 0xD8 || m == 0x01 || (m >= 0xD0 && m <= 0xD7)) { r += 2; continue; }
		len = (size_t)p[r + 2] << 8 | p[r + 3];
		if (m == 0xD9 || len < 2 || r + 2 + len > n)
			return 0;
		r += 2 + len;
		if (m == 0xDA)
			return r;
	}
	return 0;
}

/* Removes every DHT (FFC4) segment before the scan data, in place. */
static size_t jpeg_strip_dht(unsigned char *p, size_t n)
{
	size_t r = 2, w = 2;
	if (n < 4 || p[0] != 0xFF || p[1] != 0xD8)
		return n;
	while (r + 4 <= n && p[r] == 0xFF) {
		unsigned m = p[r + 1];
		size_t len, seg;
		if (m == 0xFF) { r++; continue; }
		if (m == 0xD8 || m == 0x01 || (m >= 0xD0 && m <= 0xD7)) len = 0;
		else len = (size_t)p[r + 2] << 8 | p[r + 3];
		if (m == 0xD9 || (len && len < 2) || r + 2 + len > n)
			break;
		seg = 2 + len;
		if (m != 0xC4) {
			memmove(p + w, p + r, seg);
			w += seg;
		}
		r += seg;
		if (m == 0xDA)
			break;
	}
	memmove(p + w, p + r, n - r);
	return w + (n - r);
}

/* Garbage entropy data, cut to half, no EOI. */
static size_t jpeg_corrupt(unsigned char *p, size_t n)
{
	size_t s = jpeg_scan_start(p, n), i, end;
	uint32_t x = 0x12345678u;
	if (!s)
		s = n < 2 ? n : 2;
	end = s + (n - s) / 2;
	for (i = s; i < end; i++) {
		x = x * 1103515245u + 12345u;
		p[i] = (x >> 16) & 0xFF;
		if (p[i] == 0xFF)
			p[i] = 0xFE;
	}
	return end;
}

/* ----------------------------------------------------------- frame fill */

static ssize_t read_file_into(const char *path, unsigned char *dst, size_t cap)
{
	int fd = dev.real.open(path, O_RDONLY | O_CLOEXEC);
	size_t got = 0;
	if (fd < 0)
		return -1;
	while (got < cap) {
		ssize_t n = dev.real.read(fd, dst + got, cap - got);
		if (n < 0 && errno == EINTR)
			continue;
		if (n <= 0)
			break;
		got += n;
	}
	dev.real.close(fd);
	return got;
}

static unsigned char clamp8(int v) { return v < 0 ? 0 : v > 255 ? 255 : v; }

static void yuyv_apply(unsigned char *p, size_t n, int exposure, int temp)
{
	int du = (temp - 4600) / 50;
	size_t i;
	if (exposure == 250 && du == 0)
		return;
	for (i = 0; i + 3 < n; i += 4) {
		p[i] = clamp8((p[i] * exposure + 125) / 250);
		p[i + 1] = clamp8(p[i + 1] + du);
		p[i + 2] = clamp8((p[i + 2] * exposure + 125) / 250);
		p[i + 3] = clamp8(p[i + 3] - du);
	}
}

static enum fill_result fill_mjpeg(const struct fc_frame *f, struct fc_buf *b,
				   unsigned char *dst, int corrupt)
{
	ssize_t n = read_file_into(f->jpeg, dst, dev.stride);
	if (n < 0) {
		b->bytesused = 0;
		b->flags |= V4L2_BUF_FLAG_ERROR;
		return FILL_READERR;
	}
	if (!dev.keep_dht)
		n = jpeg_strip_dht(dst, n);
	if (corrupt)
		n = jpeg_corrupt(dst, n);
	b->bytesused = n;
	return corrupt ? FILL_CORRUPT : FILL_OK;
}

static enum fill_result fill_yuyv(const struct fc_frame *f, struct fc_buf *b,
				  unsigned char *dst, int corrupt, uint32_t seq)
{
	size_t size = (size_t)dev.w * 2 * dev.h;
	ssize_t n = read_file_into(f->yuyv, dst, size);
	if (n < 0 || (size_t)n != size) {
		b->bytesused = 0;
		b->flags |= V4L2_BUF_FLAG_ERROR;
		return FILL_READERR;
	}
	yuyv_apply(dst, size, ctrl_value_at(C_EXP_ABS, seq), ctrl_value_at(C_WB_TEMP, seq));
	b->bytesused = size;
	if (corrupt) {
		b->bytesused = size / 2;
		b->flags |= V4L2_BUF_FLAG_ERROR;
		return FILL_CORRUPT;
	}
	return FILL_OK;
}

static int oldest(enum buf_state st)
{
	int best = -1;
	unsigned i;
	for (i = 0; i < dev.nbufs; i++)
		if (dev.bufs[i].state == st && (best < 0 || dev.bufs[i].order < dev.bufs[best].order))
			best = i;
	return best;
}

static void timestamp_now(struct timeval *tv)
{
	long long ns = now_ns();
	tv->tv_sec = ns / 1000000000LL;
	tv->tv_usec = (ns % 1000000000LL) / 1000;
}

static void fill_buffer(int idx, uint32_t seq, int corrupt)
{
	static const char *result_name[] = { "ok", "corrupt", "readerr" };
	struct fc_buf *b = &dev.bufs[idx];
	unsigned char *dst = dev.mem + idx * dev.stride;
	const struct fc_frame *f;
	enum fill_result res;
	int t, r;
	char cc[5];

	read_pose(&t, &r);
	f = bank_pick(t, r);
	b->flags = 0;
	if (dev.fourcc == V4L2_PIX_FMT_MJPEG)
		res = fill_mjpeg(f, b, dst, corrupt);
	else
		res = fill_yuyv(f, b, dst, corrupt, seq);
	b->sequence = seq;
	timestamp_now(&b->ts);
	b->state = BUF_DONE;
	b->order = dev.order_ctr++;
	fourcc_str(dev.fourcc, cc);
	log_line("frame %u %d %d %d %d %s %u %s", seq, t, r, f->table, f->rail, cc,
		 b->bytesused, result_name[res]);
}

static void unplug(struct fc_fault *f)
{
	if (f->ms)
		log_line("fault unplug@%ld:%ld", f->n, f->ms);
	else
		log_line("fault unplug@%ld", f->n);
	dev.unplugged = 1;
	dev.unplug_until = f->ms ? now_ns() + f->ms * 1000000LL : -1;
	dev.configured = 0;             /* a replugged camera has defaults */
}

/* One sensor frame: fill the oldest queued buffer, or drop the frame. */
static void sensor_tick(void)
{
	struct fc_fault *f;
	uint32_t seq;
	int idx;

	if (dev.stalled)
		return;
	seq = dev.seq++;
	idx = oldest(BUF_QUEUED);
	if (idx < 0)
		return;
	if ((f = fire_fault(F_UNPLUG, dev.frames_filled))) {
		unplug(f);
		return;
	}
	if ((f = fire_fault(F_STALL, dev.frames_filled))) {
		log_line("fault stall@%ld", f->n);
		dev.stalled = 1;
		return;
	}
	f = fire_fault(F_CORRUPT, dev.frames_filled);
	if (f)
		log_line("fault corrupt@%ld", f->n);
	fill_buffer(idx, seq, f != NULL);
	dev.frames_filled++;
}

static void *clock_main(void *arg)
{
	long long next;
	(void)arg;
	lock();
	next = now_ns();
	while (dev.clock_run && !dev.unplugged) {
		long long iv = frame_interval_ns();
		next += iv;
		while (dev.clock_run && now_ns() < next)
			wait_until(next);
		if (!dev.clock_run)
			break;
		if (now_ns() > next + 4 * iv)
			next = now_ns();        /* fell behind: resynchronise */
		sensor_tick();
		pthread_cond_broadcast(&dev.cv);
	}
	unlock();
	return NULL;
}

/* Stops and joins the sensor thread; drops the lock while joining. */
static void clock_stop(void)
{
	pthread_t t = dev.thread;
	dev.clock_run = 0;
	pthread_cond_broadcast(&dev.cv);
	if (!dev.have_thread)
		return;
	dev.have_thread = 0;
	unlock();
	pthread_join(t, NULL);
	lock();
}

static int clock_start(void)
{
	dev.clock_run = 1;
	if (pthread_create(&dev.thread, NULL, clock_main, NULL) != 0) {
		dev.clock_run = 0;
		return EAGAIN;
	}
	dev.have_thread = 1;
	return 0;
}

/* -------------------------------------------------------------- buffers */

static void buffers_free(void)
{
	unsigned i;
	if (dev.mem)
		dev.real.munmap(dev.mem, dev.nbufs * dev.stride);
	dev.mem = NULL;
	for (i = 0; i < MAX_BUFS; i++)
		__atomic_store_n(&dev.bufs[i].map_addr, NULL, __ATOMIC_RELEASE);
	memset(dev.bufs, 0, sizeof dev.bufs);
	dev.nbufs = 0;
}

static int do_reqbufs(struct v4l2_requestbuffers *rb)
{
	unsigned count = rb->count;
	size_t stride;
	void *mem;

	if (rb->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || rb->memory != V4L2_MEMORY_MMAP)
		return EINVAL;
	if (dev.streaming)
		return EBUSY;
	buffers_free();
	rb->capabilities = V4L2_BUF_CAP_SUPPORTS_MMAP;
	if (count == 0)
		return 0;
	count = count < MIN_BUFS ? MIN_BUFS : count > MAX_BUFS ? MAX_BUFS : count;
	stride = page_round(fmt_sizeimage(dev.fourcc, dev.w, dev.h));
	if (ftruncate(dev.fd, count * stride) < 0)
		return ENOMEM;
	mem = dev.real.mmap(NULL, count * stride, PROT_READ | PROT_WRITE, MAP_SHARED, dev.fd, 0);
	if (mem == MAP_FAILED)
		return ENOMEM;
	dev.mem = mem;
	dev.stride = stride;
	dev.nbufs = count;
	rb->count = count;
	return 0;
}

static void fill_v4l2_buffer(struct v4l2_buffer *vb, unsigned i)
{
	struct fc_buf *b = &dev.bufs[i];
	memset(vb, 0, sizeof *vb);
	vb->index = i;
	vb->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
	vb->memory = V4L2_MEMORY_MMAP;
	vb->field = V4L2_FIELD_NONE;
	vb->m.offset = i * dev.stride;
	vb->length = fmt_sizeimage(dev.fourcc, dev.w, dev.h);
	vb->flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | b->flags;
	if (b->map_addr) vb->flags |= V4L2_BUF_FLAG_MAPPED;
	if (b->state == BUF_QUEUED) vb->flags |= V4L2_BUF_FLAG_QUEUED;
	if (b->state == BUF_DONE) vb->flags |= V4L2_BUF_FLAG_DONE;
	if (b->state != BUF_QUEUED) {
		vb->bytesused = b->bytesused;
		vb->sequence = b->sequence;
		vb->timestamp = b->ts;
	}
}

static int check_buffer_arg(const struct v4l2_buffer *vb, int want_index)
{
	if (vb->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || vb->memory != V4L2_MEMORY_MMAP)
		return EINVAL;
	if (want_index && vb->index >= dev.nbufs)
		return EINVAL;
	return 0;
}

static int do_querybuf(struct v4l2_buffer *vb)
{
	int err = check_buffer_arg(vb, 1);
	if (err)
		return err;
	fill_v4l2_buffer(vb, vb->index);
	return 0;
}

static int do_qbuf(struct v4l2_buffer *vb)
{
	int err = check_buffer_arg(vb, 1);
	struct fc_buf *b;
	if (err)
		return err;
	b = &dev.bufs[vb->index];
	if (b->state != BUF_DEQUEUED)
		return EINVAL;
	b->state = BUF_QUEUED;
	b->order = dev.order_ctr++;
	b->flags = 0;
	b->bytesused = 0;
	fill_v4l2_buffer(vb, vb->index);
	return 0;
}

static int do_dqbuf(struct v4l2_buffer *vb, int fd)
{
	unsigned gen = dev.gen;
	int err = check_buffer_arg(vb, 0), idx;
	if (err)
		return err;
	for (;;) {
		if (dev.gen != gen || dev.fd != fd)
			return EBADF;
		if (dev.unplugged)
			return ENODEV;
		if (!dev.streaming)
			return EINVAL;
		idx = oldest(BUF_DONE);
		if (idx >= 0)
			break;
		if (fcntl(fd, F_GETFL) & O_NONBLOCK)
			return EAGAIN;
		wait_until(-1);
	}
	fill_v4l2_buffer(vb, idx);
	vb->flags &= ~V4L2_BUF_FLAG_DONE;
	dev.bufs[idx].state = BUF_DEQUEUED;
	log_line("dqbuf %d %u", idx, vb->sequence);
	return 0;
}

static int do_streamon(const int *type)
{
	int err;
	if (*type != V4L2_BUF_TYPE_VIDEO_CAPTURE || dev.nbufs == 0)
		return EINVAL;
	if (dev.streaming)
		return 0;
	dev.seq = 0;
	dev.stalled = 0;
	err = clock_start();
	if (err)
		return err;
	dev.streaming = 1;
	log_line("streamon");
	return 0;
}

/* Stops the clock and returns every buffer to the dequeued state. */
static void stream_stop(void)
{
	unsigned i;
	clock_stop();
	dev.streaming = 0;
	dev.stalled = 0;
	for (i = 0; i < dev.nbufs; i++) {
		dev.bufs[i].state = BUF_DEQUEUED;
		dev.bufs[i].flags = 0;
	}
	pthread_cond_broadcast(&dev.cv);
}

static int do_streamoff(const int *type)
{
	if (*type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
		return EINVAL;
	stream_stop();
	log_line("streamoff");
	return 0;
}

/* -------------------------------------------------------------- ioctl */

static int do_querycap(struct v4l2_capability *c)
{
	memset(c, 0, sizeof *c);
	snprintf((char *)c->driver, sizeof c->driver, "uvcvideo");
	snprintf((char *)c->card, sizeof c->card, "cac fake UVC camera");
	snprintf((char *)c->bus_info, sizeof c->bus_info, "usb-fakecam-1");
	c->version = (6u << 16) | (1u << 8);   /* 6.1.0 */
	c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
	c->capabilities = c->device_caps | V4L2_CAP_DEVICE_CAPS;
	return 0;
}

static int do_enuminput(struct v4l2_input *in)
{
	uint32_t idx = in->index;
	if (idx != 0)
		return EINVAL;
	memset(in, 0, sizeof *in);
	snprintf((char *)in->name, sizeof in->name, "Camera 1");
	in->type = V4L2_INPUT_TYPE_CAMERA;
	return 0;
}

static int dispatch(int fd, unsigned long req, void *arg)
{
	switch (req) {
	case VIDIOC_QUERYCAP: return do_querycap(arg);
	case VIDIOC_ENUM_FMT: return do_enum_fmt(arg);
	case VIDIOC_ENUM_FRAMESIZES: return do_enum_framesizes(arg);
	case VIDIOC_ENUM_FRAMEINTERVALS: return do_enum_frameintervals(arg);
	case VIDIOC_G_FMT: return do_g_fmt(arg);
	case VIDIOC_S_FMT: return do_s_fmt(arg);
	case VIDIOC_TRY_FMT: return try_fmt(arg);
	case VIDIOC_G_PARM: return do_g_parm(arg);
	case VIDIOC_S_PARM: return do_s_parm(arg);
	case VIDIOC_QUERYCTRL: return do_queryctrl(arg);
	case VIDIOC_QUERYMENU: return do_querymenu(arg);
	case VIDIOC_G_CTRL: return do_g_ctrl(arg);
	case VIDIOC_S_CTRL: return do_s_ctrl(arg);
	case VIDIOC_G_EXT_CTRLS:
	case VIDIOC_S_EXT_CTRLS:
	case VIDIOC_TRY_EXT_CTRLS: return do_ext_ctrls(req, arg);
	case VIDIOC_REQBUFS: return do_reqbufs(arg);
	case VIDIOC_QUERYBUF: return do_querybuf(arg);
	case VIDIOC_QBUF: return do_qbuf(arg);
	case VIDIOC_DQBUF: return do_dqbuf(arg, fd);
	case VIDIOC_STREAMON: return do_streamon(arg);
	case VIDIOC_STREAMOFF: return do_streamoff(arg);
	case VIDIOC_ENUMINPUT: return do_enuminput(arg);
	case VIDIOC_G_INPUT: *(int *)arg = 0; return 0;
	case VIDIOC_S_INPUT: return *(int *)arg == 0 ? 0 : EINVAL;
	default: return ENOTTY;
	}
}

static int fake_ioctl(int fd, unsigned long req, void *arg)
{
	int err;
	lock();
	if (fd != dev.fd || dev.unplugged)
		err = ENODEV;           /* dead fd, or device gone */
	else if (!arg && req != VIDIOC_LOG_STATUS)
		err = EFAULT;
	else
		err = dispatch(fd, req, arg);
	unlock();
	return err ? fail(err) : 0;
}

/* ------------------------------------------------------------ open/close */

static void instance_reset(void)
{
	buffers_free();
	dev.streaming = dev.stalled = dev.unplugged = 0;
	dev.fd = -1;
	dev.gen++;
}

static void add_dead_fd(int fd)
{
	int i;
	for (i = 0; i < MAX_DEAD; i++)
		if (dev.dead[i] < 0) {
			__atomic_store_n(&dev.dead[i], fd, __ATOMIC_RELEASE);
			return;
		}
}

/* An unplugged instance still open: its fd becomes a dead fd. */
static void orphan_instance(void)
{
	clock_stop();
	add_dead_fd(dev.fd);
	__atomic_store_n(&dev.fd, -1, __ATOMIC_RELEASE);
	instance_reset();
	pthread_cond_broadcast(&dev.cv);
}

static int fake_open_locked(int flags)
{
	int fd;

	if (dev.unplug_until == -1 || (dev.unplug_until > 0 && now_ns() < dev.unplug_until))
		return fail(ENOENT);
	dev.unplug_until = 0;
	if (dev.fd >= 0 && dev.unplugged)
		orphan_instance();
	if (dev.fd >= 0)
		return fail(EBUSY);
	if (bank_load() < 0)
		return fail(ENOENT);
	settings_validate();
	fd = memfd_create("fakecam", MFD_CLOEXEC);
	if (fd < 0)
		return -1;
	if (flags & O_NONBLOCK)
		fcntl(fd, F_SETFL, O_NONBLOCK);
	instance_reset();
	__atomic_store_n(&dev.fd, fd, __ATOMIC_RELEASE);
	log_line("open");
	return fd;
}

static int fake_open(int flags)
{
	int fd;
	lock();
	fd = fake_open_locked(flags);
	unlock();
	return fd;
}

static int fake_close(int fd)
{
	int i;
	lock();
	for (i = 0; i < MAX_DEAD; i++)
		if (dev.dead[i] == fd) {
			__atomic_store_n(&dev.dead[i], -1, __ATOMIC_RELEASE);
			log_line("close");
		}
	if (fd == dev.fd) {
		stream_stop();
		__atomic_store_n(&dev.fd, -1, __ATOMIC_RELEASE);
		instance_reset();
		bank_free();
		log_line("close");
	}
	pthread_cond_broadcast(&dev.cv);
	unlock();
	return dev.real.close(fd);
}

static int mode_arg(int flags, va_list ap)
{
	return (flags & O_CREAT) || (flags & O_TMPFILE) == O_TMPFILE ? va_arg(ap, int) : 0;
}

/* The open family: the emulated node is answered here, every other path goes to libc with its
 * mode (read from the variadic argument only when the flags say there is one). Each symbol
 * has to exist on its own for the interposition, so one macro writes the four. */
#define INTERPOSE_OPEN(name, params, args)                  \
	int name params                                         \
	{                                                       \
		va_list ap;                                         \
		int mode;                                           \
		va_start(ap, flags);                                \
		mode = mode_arg(flags, ap);                         \
		va_end(ap);                                         \
		if (is_fake_path(path))                             \
			return fake_open(flags);                        \
		return dev.real.name args;                          \
	}

INTERPOSE_OPEN(open, (const char *path, int flags, ...), (path, flags, mode))
INTERPOSE_OPEN(open64, (const char *path, int flags, ...), (path, flags, mode))
INTERPOSE_OPEN(openat, (int dirfd, const char *path, int flags, ...), (dirfd, path, flags, mode))
INTERPOSE_OPEN(openat64, (int dirfd, const char *path, int flags, ...), (dirfd, path, flags, mode))

/* _FORTIFY_SOURCE entry points. */
int __open_2(const char *path, int flags) { return open(path, flags); }
int __open64_2(const char *path, int flags) { return open64(path, flags); }

int close(int fd)
{
	fc_init();
	if (is_fake_fd(fd))
		return fake_close(fd);
	return dev.real.close(fd);
}

int ioctl(int fd, unsigned long req, ...)
{
	va_list ap;
	void *arg;
	va_start(ap, req);
	arg = va_arg(ap, void *);
	va_end(ap);
	fc_init();
	if (is_fake_fd(fd))
		return fake_ioctl(fd, req, arg);
	return dev.real.ioctl(fd, req, arg);
}

ssize_t read(int fd, void *buf, size_t n)
{
	fc_init();
	if (is_fake_fd(fd)) {
		int gone;
		lock();
		gone = fd != dev.fd || dev.unplugged;
		unlock();
		return fail(gone ? ENODEV : EINVAL);
	}
	return dev.real.read(fd, buf, n);
}

/* ----------------------------------------------------------- mmap */

static void *fake_mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off)
{
	void *p = MAP_FAILED;
	unsigned i;
	int err = EINVAL;

	lock();
	if (fd != dev.fd || dev.unplugged) {
		err = ENODEV;
	} else if ((flags & MAP_SHARED) && len > 0 && dev.stride && off >= 0 &&
		   (size_t)off % dev.stride == 0 && (size_t)off / dev.stride < dev.nbufs &&
		   len <= dev.stride) {
		i = (size_t)off / dev.stride;
		p = dev.real.mmap(addr, len, prot, flags, fd, off);
		if (p == MAP_FAILED)
			err = errno;
		else
			__atomic_store_n(&dev.bufs[i].map_addr, p, __ATOMIC_RELEASE);
	}
	unlock();
	if (p == MAP_FAILED)
		errno = err;
	return p;
}

void *mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off)
{
	fc_init();
	if (is_fake_fd(fd))
		return fake_mmap(addr, len, prot, flags, fd, off);
	return dev.real.mmap(addr, len, prot, flags, fd, off);
}

void *mmap64(void *addr, size_t len, int prot, int flags, int fd, off64_t off)
{
	fc_init();
	if (is_fake_fd(fd))
		return fake_mmap(addr, len, prot, flags, fd, off);
	return dev.real.mmap64(addr, len, prot, flags, fd, off);
}

/* Lock-free address check first: internal frees must never take the lock. */
int munmap(void *addr, size_t len)
{
	unsigned i;
	fc_init();
	for (i = 0; addr && i < MAX_BUFS; i++) {
		if (__atomic_load_n(&dev.bufs[i].map_addr, __ATOMIC_ACQUIRE) != addr)
			continue;
		lock();
		if (dev.bufs[i].map_addr == addr)
			__atomic_store_n(&dev.bufs[i].map_addr, NULL, __ATOMIC_RELEASE);
		unlock();
	}
	return dev.real.munmap(addr, len);
}

/* ----------------------------------------------------------- poll */

static short fake_revents(int fd, short events)
{
	short r;
	if (fd != dev.fd || dev.unplugged)
		r = POLLERR | POLLHUP;
	else if (!dev.streaming)
		r = POLLERR;
	else if (oldest(BUF_DONE) >= 0)
		r = POLLIN | POLLRDNORM;
	else
		r = 0;
	return r & (events | POLLERR | POLLHUP);
}

/* Sets revents of the fake entries; returns how many are ready. */
static int scan_fake(struct pollfd *fds, nfds_t n)
{
	nfds_t i;
	int ready = 0;
	for (i = 0; i < n; i++) {
		if (!is_fake_fd(fds[i].fd))
			continue;
		fds[i].revents = fake_revents(fds[i].fd, fds[i].events);
		ready += fds[i].revents != 0;
	}
	return ready;
}

/* Real poll of the other fds, hiding the fake entries (fd -> -1). */
static int poll_others(struct pollfd *fds, nfds_t n, int timeout_ms)
{
	nfds_t i;
	int rc, saved_errno;
	short *saved_rev = alloca(n * sizeof(short));
	int *saved_fd = alloca(n * sizeof(int));

	for (i = 0; i < n; i++) {
		saved_fd[i] = fds[i].fd;
		saved_rev[i] = fds[i].revents;
		if (is_fake_fd(fds[i].fd))
			fds[i].fd = -1;
	}
	rc = dev.real.poll(fds, n, timeout_ms);
	saved_errno = errno;
	for (i = 0; i < n; i++)
		if (fds[i].fd == -1 && saved_fd[i] >= 0) {
			fds[i].fd = saved_fd[i];
			fds[i].revents = saved_rev[i];
		}
	errno = saved_errno;
	return rc;
}

static int count_others(struct pollfd *fds, nfds_t n)
{
	nfds_t i;
	int k = 0;
	for (i = 0; i < n; i++)
		k += fds[i].fd >= 0 && !is_fake_fd(fds[i].fd);
	return k;
}

/* poll() with fake fds among fds; timeout in ms, negative: forever. */
static int fake_poll(struct pollfd *fds, nfds_t n, long long timeout_ms)
{
	long long deadline = timeout_ms < 0 ? -1 : now_ns() + timeout_ms * 1000000LL;
	int others = count_others(fds, n);

	for (;;) {
		int ready, expired;
		lock();
		ready = scan_fake(fds, n);
		expired = deadline >= 0 && now_ns() >= deadline;
		if (!ready && !others && !expired) {
			wait_until(deadline);
			ready = scan_fake(fds, n);
		}
		unlock();
		if (others) {
			long long left = deadline < 0 ? 2 : (deadline - now_ns()) / 1000000LL;
			int rc = poll_others(fds, n, ready || left <= 0 ? 0 : left < 2 ? (int)left : 2);
			if (rc < 0)
				return rc;
			ready += rc;
		}
		if (ready || (deadline >= 0 && now_ns() >= deadline))
			return ready;
	}
}

static int any_fake(const struct pollfd *fds, nfds_t n)
{
	nfds_t i;
	for (i = 0; i < n; i++)
		if (is_fake_fd(fds[i].fd))
			return 1;
	return 0;
}

int poll(struct pollfd *fds, nfds_t n, int timeout)
{
	fc_init();
	if (!any_fake(fds, n))
		return dev.real.poll(fds, n, timeout);
	return fake_poll(fds, n, timeout);
}

int ppoll(struct pollfd *fds, nfds_t n, const struct timespec *tmo, const sigset_t *mask)
{
	fc_init();
	if (!any_fake(fds, n))
		return dev.real.ppoll(fds, n, tmo, mask);
	/* the signal mask is not applied for fake polls */
	return fake_poll(fds, n, tmo ? tmo->tv_sec * 1000LL + tmo->tv_nsec / 1000000 : -1);
}

static int fdset_has_fake(int nfds, fd_set *r, fd_set *w, fd_set *e)
{
	int fd;
	for (fd = 0; fd < nfds && fd < FD_SETSIZE; fd++)
		if (is_fake_fd(fd) && ((r && FD_ISSET(fd, r)) || (w && FD_ISSET(fd, w)) ||
				       (e && FD_ISSET(fd, e))))
			return 1;
	return 0;
}

/* select() through fake_poll when a fake fd is in one of the sets. */
int select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv)
{
	struct pollfd *p;
	int fd, n = 0, rc, i;

	fc_init();
	if (!fdset_has_fake(nfds, r, w, e))
		return dev.real.select(nfds, r, w, e, tv);
	if (nfds > FD_SETSIZE)
		nfds = FD_SETSIZE;
	p = alloca(nfds * sizeof *p);
	for (fd = 0; fd < nfds; fd++) {
		short ev = (r && FD_ISSET(fd, r) ? POLLIN : 0) | (w && FD_ISSET(fd, w) ? POLLOUT : 0) |
			   (e && FD_ISSET(fd, e) ? POLLPRI : 0);
		if (ev) {
			p[n].fd = fd;
			p[n].events = ev;
			p[n].revents = 0;
			n++;
		}
	}
	rc = fake_poll(p, n, tv ? tv->tv_sec * 1000LL + tv->tv_usec / 1000 : -1);
	if (rc < 0)
		return rc;
	if (r) FD_ZERO(r);
	if (w) FD_ZERO(w);
	if (e) FD_ZERO(e);
	for (i = 0, rc = 0; i < n; i++) {
		short re = p[i].revents;
		if (r && (re & (POLLIN | POLLERR | POLLHUP)) && (p[i].events & POLLIN)) { FD_SET(p[i].fd, r); rc++; }
		if (w && (re & (POLLOUT | POLLERR)) && (p[i].events & POLLOUT)) { FD_SET(p[i].fd, w); rc++; }
		if (e && (re & POLLPRI)) { FD_SET(p[i].fd, e); rc++; }
	}
	return rc;
}
