/* AprilTag 3 side of scripts/bench_vs_apriltag.sh (issue 15, item 1).
 *
 *   apriltag_bench paste SIZE_PX X Y IN.pnm OUT.pnm
 *       Paste tag36h11 id 0 (its own 1-cell white border plus one more white
 *       cell all round), scaled to SIZE_PX with nearest neighbour, with its
 *       top-left corner at (X, Y), into a binary PGM (P5) or PPM (P6) image.
 *
 *   apriltag_bench detect DECIMATE REPS IMG.pgm...
 *       Detect tag36h11 with one thread and quad_decimate DECIMATE (everything
 *       else as apriltag_detector_create sets it: sigma 0, refine_edges 1).
 *       Per image: one line
 *         "IMAGE read_ms read_cpu_ms detect_ms detect_cpu_ms ndetections found_id0"
 *       where detect_ms is the median wall time (CLOCK_MONOTONIC) of REPS calls
 *       of apriltag_detector_detect alone, detect_cpu_ms the median of the
 *       thread's CPU time (CLOCK_THREAD_CPUTIME_ID) of those calls, and read_*
 *       the time image_u8_create_from_pnm took to read the PGM file.
 *
 * Build: cc -O2 -o apriltag_bench apriltag_bench.c -I/usr/include/apriltag -lapriltag -lapriltag-utils -lm
 */
#define _POSIX_C_SOURCE 199309L
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <apriltag.h>
#include <tag36h11.h>
#include <common/image_u8.h>
#include <common/zarray.h>

static void die(const char *fmt, const char *arg) {
    fprintf(stderr, "apriltag_bench: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n");
    exit(1);
}

static int cmp_double(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double clock_ms(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}
static double now_ms(void) { return clock_ms(CLOCK_MONOTONIC); }
static double cpu_ms(void) { return clock_ms(CLOCK_THREAD_CPUTIME_ID); }

static double median(double *v, int n) {
    qsort(v, n, sizeof(double), cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* Skip whitespace and '#' comments in a PNM header. */
static void skip_ws(FILE *f) {
    int c;
    while ((c = fgetc(f)) != EOF) {
        if (c == '#') {
            while ((c = fgetc(f)) != EOF && c != '\n') {}
        } else if (c != ' ' && c != '\t' && c != '\n' && c != '\r') {
            ungetc(c, f);
            return;
        }
    }
}

struct pnm {
    int width, height, channels;
    uint8_t *data;
};

static struct pnm read_pnm(const char *path) {
    struct pnm p = {0};
    FILE *f = fopen(path, "rb");
    if (!f) die("cannot open %s", path);
    char magic[3] = {0};
    int maxval = 0;
    if (fread(magic, 1, 2, f) != 2) die("%s: not a PNM file", path);
    if (strcmp(magic, "P5") == 0) p.channels = 1;
    else if (strcmp(magic, "P6") == 0) p.channels = 3;
    else die("%s: only binary PGM (P5) and PPM (P6) are read", path);
    skip_ws(f);
    if (fscanf(f, "%d", &p.width) != 1) die("%s: bad header", path);
    skip_ws(f);
    if (fscanf(f, "%d", &p.height) != 1) die("%s: bad header", path);
    skip_ws(f);
    if (fscanf(f, "%d", &maxval) != 1) die("%s: bad header", path);
    if (maxval != 255 || p.width <= 0 || p.height <= 0) die("%s: only 8-bit images", path);
    fgetc(f); /* the single whitespace after maxval */
    size_t n = (size_t)p.width * p.height * p.channels;
    p.data = malloc(n);
    if (!p.data) die("%s: out of memory", path);
    if (fread(p.data, 1, n, f) != n) die("%s: truncated", path);
    fclose(f);
    return p;
}

static void write_pnm(const char *path, const struct pnm *p) {
    FILE *f = fopen(path, "wb");
    if (!f) die("cannot write %s", path);
    fprintf(f, "P%d\n%d %d\n255\n", p->channels == 1 ? 5 : 6, p->width, p->height);
    size_t n = (size_t)p->width * p->height * p->channels;
    if (fwrite(p->data, 1, n, f) != n) die("writing %s failed", path);
    if (fclose(f) != 0) die("writing %s failed", path);
}

static int cmd_paste(int argc, char **argv) {
    if (argc != 7) die("%s", "usage: paste SIZE_PX X Y IN.pnm OUT.pnm");
    int size = atoi(argv[2]), x0 = atoi(argv[3]), y0 = atoi(argv[4]);
    struct pnm img = read_pnm(argv[5]);
    if (size < 12 || x0 < 0 || y0 < 0 || x0 + size > img.width || y0 + size > img.height)
        die("%s: the tag does not fit in the image there", argv[5]);
    apriltag_family_t *tf = tag36h11_create();
    image_u8_t *tag = apriltag_to_image(tf, 0); /* 10x10 cells: 1 white, 1 black, 6x6 data */
    int cells = tag->width + 2;                 /* and one more white cell all round */
    for (int y = 0; y < size; y++) {
        int cy = y * cells / size - 1;
        for (int x = 0; x < size; x++) {
            int cx = x * cells / size - 1;
            uint8_t v = 255;
            if (cx >= 0 && cy >= 0 && cx < tag->width && cy < tag->height) v = tag->buf[cy * tag->stride + cx];
            uint8_t *px = img.data + ((size_t)(y0 + y) * img.width + (x0 + x)) * img.channels;
            for (int c = 0; c < img.channels; c++) px[c] = v;
        }
    }
    image_u8_destroy(tag);
    tag36h11_destroy(tf);
    write_pnm(argv[6], &img);
    free(img.data);
    return 0;
}

static int cmd_detect(int argc, char **argv) {
    if (argc < 5) die("%s", "usage: detect DECIMATE REPS IMG.pgm...");
    double decimate = atof(argv[2]);
    int reps = atoi(argv[3]);
    if (decimate < 1.0 || reps < 1) die("%s", "DECIMATE must be >= 1 and REPS >= 1");
    apriltag_family_t *tf = tag36h11_create();
    apriltag_detector_t *td = apriltag_detector_create();
    apriltag_detector_add_family(td, tf);
    td->quad_decimate = (float)decimate;
    td->nthreads = 1;
    double *times = malloc(sizeof(double) * reps);
    double *cpus = malloc(sizeof(double) * reps);
    for (int i = 4; i < argc; i++) {
        double t0 = now_ms(), c0 = cpu_ms();
        image_u8_t *im = image_u8_create_from_pnm(argv[i]);
        double read_ms = now_ms() - t0, read_cpu = cpu_ms() - c0;
        if (!im) die("cannot read %s as PGM", argv[i]);
        int ndet = 0, found = 0;
        for (int r = 0; r < reps; r++) {
            double t = now_ms(), c = cpu_ms();
            zarray_t *dets = apriltag_detector_detect(td, im);
            times[r] = now_ms() - t;
            cpus[r] = cpu_ms() - c;
            if (r == 0) {
                ndet = zarray_size(dets);
                for (int k = 0; k < ndet; k++) {
                    apriltag_detection_t *det;
                    zarray_get(dets, k, &det);
                    if (det->id == 0) found = 1;
                }
            }
            apriltag_detections_destroy(dets);
        }
        printf("%s %.4f %.4f %.4f %.4f %d %d\n", argv[i], read_ms, read_cpu, median(times, reps),
               median(cpus, reps), ndet, found);
        image_u8_destroy(im);
    }
    free(times);
    free(cpus);
    apriltag_detector_destroy(td);
    tag36h11_destroy(tf);
    return 0;
}

int main(int argc, char **argv) {
    if (argc >= 2 && strcmp(argv[1], "paste") == 0) return cmd_paste(argc, argv);
    if (argc >= 2 && strcmp(argv[1], "detect") == 0) return cmd_detect(argc, argv);
    fprintf(stderr, "usage: apriltag_bench paste SIZE_PX X Y IN.pnm OUT.pnm\n"
                    "       apriltag_bench detect DECIMATE REPS IMG.pgm...\n");
    return 2;
}
