/*
 * The fused correction of picamcal.kernels in C: black, flat field, Malvar-He-Cutler demosaic with mirrored
 * borders, the spline-interpolated 3x3 matrix field, and float32 or uint16 output, in one pass over the frame.
 *
 * picamcal.ckernel compiles this file once per installation (flags there: -O3 -march=native -ffp-contract=off, no
 * fast-math) and calls picamcal_correct through ctypes. The float32 operations are those of the numba kernel in
 * picamcal/kernels.py, in the same order, so the result is numpy's (correct_numpy) to the bit: every sum below is
 * written with the parentheses of the numpy expression it stands for, and -ffp-contract=off keeps a multiply and
 * an add two roundings (aarch64 gcc fuses them by default). The layouts are the numba kernel's; see
 * picamcal.kernels.CorrectionFields for the fields.
 *
 * Threads: POSIX threads take blocks of block_rows rows one at a time from an atomic counter (a core slowed by
 * other work takes fewer); each thread has its own 5-row ring of flat-fielded mosaic rows and a few planar rows.
 */
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

/* Everything one correction needs; mirrored by picamcal.ckernel._Job (same fields, same order). */
typedef struct {
    const uint16_t *bayer;            /* (height, width) */
    int64_t height, width;
    const float *black;               /* (4,) per site of the 2x2 block, row-major */
    const int64_t *channels;          /* (4,) channel of each site: 0 R, 1 G, 2 B */
    const float *site_gains;          /* (4,) used when white is NULL */
    const float *white;               /* (4, white_ny, width / 2) or NULL */
    int64_t white_ny;
    const int64_t *white_first;       /* (height,) */
    const float *white_weights;       /* (4, height) */
    const float *matrices;            /* (9, matrix_ny, matrix_nx) or NULL */
    int64_t matrix_ny, matrix_nx;
    const int64_t *matrix_row_first;  /* (height,) */
    const float *matrix_row_weights;  /* (4, height) */
    const int64_t *matrix_col_first;  /* (width,) */
    const float *matrix_col_weights;  /* (4, width) */
    const uint64_t *matrix_runs;      /* (n_runs + 1,) start of each run of equal first, then width */
    int64_t n_runs;
    float *floats;                    /* (height, width, 3), or NULL for codes */
    uint16_t *codes;                  /* (height, width, 3), or NULL for floats */
    float code_scale;
    int64_t block_rows;
    int64_t threads;
} picamcal_job;

/* For picamcal.ckernel to check that its mirror of the struct has the same size. */
size_t picamcal_job_size(void) { return sizeof(picamcal_job); }

static const float F05 = 0.5f, F15 = 1.5f, F2 = 2.0f, F4 = 4.0f, F5 = 5.0f, F6 = 6.0f, EIGHTH = 0.125f;
static const float CODE_MAX = 65535.0f;

/* Black-subtracted, flat-fielded mosaic row y as two planes of half + 2 (even then odd columns), each padded by
 * one column each side with the mirrored columns (scipy.ndimage's reflect: -1 -> 0, -2 -> 1). */
static void flat_row(const picamcal_job *job, int64_t y, float *restrict dst) {
    const int64_t half = job->width / 2, height = job->height;
    const int64_t sy = y & 1;
    const uint16_t *restrict raw = job->bayer + y * job->width;
    float *restrict even = dst + 1, *restrict odd = dst + (half + 2) + 1;
    const float level0 = job->black[2 * sy], level1 = job->black[2 * sy + 1];
    if (job->white) {
        const int64_t i = job->white_first[y];
        const float *wy = job->white_weights;
        const float w0 = wy[y], w1 = wy[height + y], w2 = wy[2 * height + y], w3 = wy[3 * height + y];
        const float *restrict e0 = job->white + ((2 * sy) * job->white_ny + i) * half;
        const float *restrict o0 = job->white + ((2 * sy + 1) * job->white_ny + i) * half;
        const float *restrict e1 = e0 + half, *restrict e2 = e1 + half, *restrict e3 = e2 + half;
        const float *restrict o1 = o0 + half, *restrict o2 = o1 + half, *restrict o3 = o2 + half;
        for (int64_t j = 0; j < half; j++) {
            even[j] = ((float)raw[2 * j] - level0) / (((w0 * e0[j] + w1 * e1[j]) + w2 * e2[j]) + w3 * e3[j]);
            odd[j] = ((float)raw[2 * j + 1] - level1) / (((w0 * o0[j] + w1 * o1[j]) + w2 * o2[j]) + w3 * o3[j]);
        }
    } else {
        const float gain0 = job->site_gains[2 * sy], gain1 = job->site_gains[2 * sy + 1];
        for (int64_t j = 0; j < half; j++) {
            even[j] = ((float)raw[2 * j] - level0) * gain0;
            odd[j] = ((float)raw[2 * j + 1] - level1) * gain1;
        }
    }
    float *plane0 = dst, *plane1 = dst + half + 2;
    plane0[0] = plane1[1];
    plane1[0] = plane0[1];
    plane0[half + 1] = plane1[half];
    plane1[half + 1] = plane0[half];
}

/* Malvar-He-Cutler on the flat rows y - 2 .. y + 2 (r[0] .. r[4], two padded planes each) of a row whose pixel
 * 2j + gx is green and 2j + nx its red or blue ("own"), into the planar row's green, own and other colour. Inlined
 * with gx a constant, for the loop to vectorise. */
static inline __attribute__((always_inline)) void demosaic_pairs(float *const r[5], const int64_t gx,
                                                                  const int64_t half, float *restrict green,
                                                                  float *restrict own, float *restrict other) {
    const int64_t nx = 1 - gx, stride = half + 2;
    const float *restrict g0 = r[0] + gx * stride, *restrict g1 = r[1] + gx * stride, *restrict g2 = r[2] + gx * stride;
    const float *restrict g3 = r[3] + gx * stride, *restrict g4 = r[4] + gx * stride;
    const float *restrict n0 = r[0] + nx * stride, *restrict n1 = r[1] + nx * stride, *restrict n2 = r[2] + nx * stride;
    const float *restrict n3 = r[3] + nx * stride, *restrict n4 = r[4] + nx * stride;
    for (int64_t j = 0; j < half; j++) {
        float v = g2[j + 1];
        float diagonal = ((n1[j + gx] + n1[j + gx + 1]) + n3[j + gx]) + n3[j + gx + 1];
        const float horizontal1 = n2[j + gx] + n2[j + gx + 1];
        const float horizontal2 = g2[j] + g2[j + 2];
        const float vertical1 = g1[j + 1] + g3[j + 1];
        const float vertical2 = g0[j + 1] + g4[j + 1];
        green[2 * j + gx] = v;
        own[2 * j + gx] = ((((F5 * v + F4 * horizontal1) - horizontal2) - diagonal) + F05 * vertical2) * EIGHTH;
        other[2 * j + gx] = ((((F5 * v + F4 * vertical1) - vertical2) - diagonal) + F05 * horizontal2) * EIGHTH;
        v = n2[j + 1];
        const float cross = ((n1[j + 1] + n3[j + 1]) + g2[j + nx]) + g2[j + nx + 1];
        const float axial2 = ((n0[j + 1] + n4[j + 1]) + n2[j]) + n2[j + 2];
        diagonal = ((g1[j + nx] + g1[j + nx + 1]) + g3[j + nx]) + g3[j + nx + 1];
        own[2 * j + nx] = v;
        green[2 * j + nx] = ((F4 * v + F2 * cross) - axial2) * EIGHTH;
        other[2 * j + nx] = ((F6 * v + F2 * diagonal) - F15 * axial2) * EIGHTH;
    }
}

/* Malvar-He-Cutler at row y into the planar row rgb (3, width). */
static void demosaic_row(float *const r[5], int64_t y, const picamcal_job *job, float *restrict rgb) {
    const int64_t width = job->width, sy = y & 1;
    const int64_t c_even = job->channels[2 * sy], c_odd = job->channels[2 * sy + 1];
    const int64_t colour = c_even == 1 ? c_odd : c_even;
    float *green = rgb + width, *own = rgb + colour * width, *other = rgb + (2 - colour) * width;
    if (c_even == 1) {
        demosaic_pairs(r, 0, width / 2, green, own, other);
    } else {
        demosaic_pairs(r, 1, width / 2, green, own, other);
    }
}

/* The matrix field at row y applied to the planar row rgb, into mixed (3, width). along (9, matrix_nx) takes the
 * field's coefficients evaluated along y; then run by run (the pixels between two knots share 4 coefficients). */
static void unmix_row(const picamcal_job *job, int64_t y, float *restrict along, const float *restrict rgb,
                      float *restrict mixed) {
    const int64_t width = job->width, height = job->height, nx = job->matrix_nx;
    const int64_t i = job->matrix_row_first[y];
    const float *wy = job->matrix_row_weights;
    const float w0 = wy[y], w1 = wy[height + y], w2 = wy[2 * height + y], w3 = wy[3 * height + y];
    for (int64_t k = 0; k < 9; k++) {
        const float *restrict c0 = job->matrices + (k * job->matrix_ny + i) * nx;
        const float *restrict c1 = c0 + nx, *restrict c2 = c1 + nx, *restrict c3 = c2 + nx;
        float *restrict a = along + k * nx;
        for (int64_t j = 0; j < nx; j++) {
            a[j] = ((w0 * c0[j] + w1 * c1[j]) + w2 * c2[j]) + w3 * c3[j];
        }
    }
    const float *restrict u0 = job->matrix_col_weights, *restrict u1 = u0 + width;
    const float *restrict u2 = u1 + width, *restrict u3 = u2 + width;
    const float *restrict red = rgb, *restrict green = rgb + width, *restrict blue = rgb + 2 * width;
    for (int64_t r = 0; r < job->n_runs; r++) {
        const int64_t x0 = (int64_t)job->matrix_runs[r], x1 = (int64_t)job->matrix_runs[r + 1];
        if (x0 >= x1) {
            continue; /* padding (runs of another parity's length): no pixel, and first[x0] may lie past the row */
        }
        const int64_t k = job->matrix_col_first[x0];
        for (int p = 0; p < 3; p++) {
            const float *ap0 = along + (3 * p) * nx + k, *ap1 = along + (3 * p + 1) * nx + k;
            const float *ap2 = along + (3 * p + 2) * nx + k;
            const float a00 = ap0[0], a10 = ap0[1], a20 = ap0[2], a30 = ap0[3];
            const float a01 = ap1[0], a11 = ap1[1], a21 = ap1[2], a31 = ap1[3];
            const float a02 = ap2[0], a12 = ap2[1], a22 = ap2[2], a32 = ap2[3];
            float *restrict d = mixed + p * width;
            for (int64_t x = x0; x < x1; x++) {
                const float m0 = ((u0[x] * a00 + u1[x] * a10) + u2[x] * a20) + u3[x] * a30;
                const float m1 = ((u0[x] * a01 + u1[x] * a11) + u2[x] * a21) + u3[x] * a31;
                const float m2 = ((u0[x] * a02 + u1[x] * a12) + u2[x] * a22) + u3[x] * a32;
                d[x] = (m0 * red[x] + m1 * green[x]) + m2 * blue[x];
            }
        }
    }
}

/* As picamcal.kernels.encode_codes: NaN and negatives fail "> 0" and give 0; rintf rounds half to even in the
 * default rounding mode, as numpy's rint. */
static inline uint16_t code(float value, float scale) {
    float v = value * scale;
    v = v > 0.0f ? v : 0.0f;
    v = v < CODE_MAX ? v : CODE_MAX;
    return (uint16_t)rintf(v);
}

static void write_row(const picamcal_job *job, int64_t y, const float *restrict rgb) {
    const int64_t width = job->width;
    const float *restrict red = rgb, *restrict green = rgb + width, *restrict blue = rgb + 2 * width;
    if (job->codes) {
        uint16_t *restrict row = job->codes + y * 3 * width;
        const float scale = job->code_scale;
        for (int64_t x = 0; x < width; x++) {
            row[3 * x] = code(red[x], scale);
            row[3 * x + 1] = code(green[x], scale);
            row[3 * x + 2] = code(blue[x], scale);
        }
    } else {
        float *restrict row = job->floats + y * 3 * width;
        for (int64_t x = 0; x < width; x++) {
            row[3 * x] = red[x];
            row[3 * x + 1] = green[x];
            row[3 * x + 2] = blue[x];
        }
    }
}

typedef struct {
    const picamcal_job *job;
    int64_t n_blocks;
    atomic_llong next; /* the next block to hand out */
} shared_work;

/* One thread: take blocks until none is left. A thread that cannot allocate its rows takes none. */
static void *work(void *arg) {
    shared_work *shared = arg;
    const picamcal_job *job = shared->job;
    const int64_t width = job->width, height = job->height, stride = job->width / 2 + 2;
    const int64_t ring_size = 5 * 2 * stride;
    float *scratch = malloc(sizeof(float) * (size_t)(ring_size + 6 * width + 9 * (job->matrix_nx + 1)));
    if (!scratch) {
        return NULL;
    }
    float *ring = scratch, *rgb = ring + ring_size, *mixed = rgb + 3 * width, *along = mixed + 3 * width;
    for (;;) {
        const int64_t block = atomic_fetch_add(&shared->next, 1);
        if (block >= shared->n_blocks) {
            break;
        }
        const int64_t y0 = block * job->block_rows;
        const int64_t y1 = y0 + job->block_rows < height ? y0 + job->block_rows : height;
        /* Flat-field row r into the 5-row ring (rows beyond the image mirrored), then demosaic the row two behind
         * it, once its neighbours r - 4 .. r are all in the ring. */
        for (int64_t r = y0 - 2; r < y1 + 2; r++) {
            const int64_t source = r < 0 ? -r - 1 : (r >= height ? 2 * height - 1 - r : r);
            flat_row(job, source, ring + ((r + 5) % 5) * 2 * stride);
            const int64_t y = r - 2;
            if (y < y0) {
                continue;
            }
            float *const rows[5] = {
                ring + ((y + 3) % 5) * 2 * stride, ring + ((y + 4) % 5) * 2 * stride, ring + (y % 5) * 2 * stride,
                ring + ((y + 1) % 5) * 2 * stride, ring + ((y + 2) % 5) * 2 * stride,
            };
            demosaic_row(rows, y, job, rgb);
            if (job->matrices) {
                unmix_row(job, y, along, rgb, mixed);
                write_row(job, y, mixed);
            } else {
                write_row(job, y, rgb);
            }
        }
    }
    free(scratch);
    return NULL;
}

/* Correct the frame with job->threads threads (the calling one among them). 0 on success; -1 when no thread
 * could allocate its rows (out of memory), in which case the output is incomplete. */
int picamcal_correct(const picamcal_job *job) {
    shared_work shared = {job, (job->height + job->block_rows - 1) / job->block_rows, 0};
    int64_t threads = job->threads < shared.n_blocks ? job->threads : shared.n_blocks;
    pthread_t *ids = threads > 1 ? malloc(sizeof(pthread_t) * (size_t)(threads - 1)) : NULL;
    int64_t started = 0;
    if (ids) {
        /* A thread that cannot start leaves its blocks to the others. */
        while (started < threads - 1 && pthread_create(&ids[started], NULL, work, &shared) == 0) {
            started++;
        }
    }
    work(&shared);
    for (int64_t t = 0; t < started; t++) {
        pthread_join(ids[t], NULL);
    }
    free(ids);
    return atomic_load(&shared.next) >= shared.n_blocks ? 0 : -1;
}
