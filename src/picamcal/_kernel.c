/*
 * The fused correction of picamcal.kernels in C: black, flat field, Malvar-He-Cutler demosaic with mirrored
 * borders, the spline-interpolated 3x3 matrix field, and float32 output or codes (uint16 linear, or the sRGB
 * formats' uint8 and uint16), in one pass over the frame; and the same codes of a float32 image (picamcal_encode).
 *
 * picamcal.ckernel compiles this file once per installation (flags there: -O3 -march=native -ffp-contract=off, no
 * fast-math) and calls picamcal_correct and picamcal_encode through ctypes. The float32 operations are those of
 * the numba kernel in picamcal/kernels.py, in the same order, so the result is numpy's (correct_numpy) to the
 * bit: every sum below is written with the parentheses of the numpy expression it stands for, and
 * -ffp-contract=off keeps a multiply and an add two roundings (aarch64 gcc fuses them by default). The layouts are
 * the numba kernel's; see picamcal.kernels.CorrectionFields for the fields.
 *
 * Threads: POSIX threads take blocks of block_rows rows one at a time from an atomic counter (a core slowed by
 * other work takes fewer); each thread has its own 6-row ring of flat-fielded mosaic rows. Rows are then
 * demosaiced, unmixed and written two at a time (the matrix field's column weights read once for both: 4 % less
 * time) and CHUNK columns at a time, their planar rows between those steps staying in the core's L1 cache.
 *
 * Where the time goes (one thread, float32 output, benchmarks/bench_correct.py prints it for the whole frame): the
 * matrix field is the most, 45 multiplications and 33 additions a pixel; then the demosaic and writing the
 * output, then the flat field. The matrix field goes run by run (the pixels between two knots share its 4
 * coefficients along x); a run is done in whole vectors of 8 pixels, and runs of up to 4 vectors (the default
 * 16-pixel bins make 2) as straight-line code: in a frame that fits the caches it then took 8.0 cycles a pixel
 * where a loop per run and channel took 11.5. Columns go CHUNK at a time so that the planar rows between the
 * steps stay in L1; the sRGB codes are looked up pixel by pixel in the tables (a gather instruction, tried,
 * took longer than the loads it stands for).
 */
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

/* GCC's and clang's vector extension: 8 floats (one AVX register on x86-64, two NEON ones on aarch64), loaded and
 * stored unaligned. Each operation is the IEEE float32 one on every lane, as the scalar code's. */
typedef float vec8 __attribute__((vector_size(32), aligned(4)));
typedef int32_t ivec8 __attribute__((vector_size(32), aligned(4)));
#define LANES 8
/* Lanes of two vectors picked by constant indices into their concatenation. */
#if defined(__clang__)
#define SHUFFLE(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)
#else
#define SHUFFLE(a, b, ...) __builtin_shuffle(a, b, (ivec8){__VA_ARGS__})
#endif

/* Columns demosaiced, unmixed and written together (a multiple of LANES); each planar row of them is padded by
 * LANES columns, which the matrix field's whole vectors may write past a run's end. */
#define CHUNK 256
#define PLANE (CHUNK + LANES)

/* What is written for each pixel; mirrored by picamcal.ckernel._KINDS. */
enum { WRITE_FLOATS = 0, WRITE_SCALED = 1, WRITE_SRGB8 = 2, WRITE_SRGB16 = 3 };

/* Mirrored by picamcal.ckernel._Output. */
typedef struct {
    void *out;                        /* (height, width, 3): float32, uint16 (SCALED, SRGB16) or uint8 (SRGB8) */
    int64_t kind;
    float scale;                      /* WRITE_SCALED: round(value * scale), as picamcal.kernels.encode_codes */
    float matrix[9];                  /* WRITE_SRGB*: linear sRGB = clip(matrix @ rgb, 0, 1), row-major */
    const void *base;                 /* WRITE_SRGB*: (cells + 1,) uint8 or uint16, the code at each cell's start */
    const float *inside;              /* (cells + 1,): the value inside each cell from which its code is one more */
    int64_t cells;                    /* a power of two: the cell of v is floor(v * cells) */
} picamcal_output;

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
    picamcal_output output;
    int64_t block_rows;
    int64_t threads;
    int64_t clip_level;               /* mosaic samples at or above it are counted into clipped */
    int64_t clipped;                  /* written by picamcal_correct */
} picamcal_job;

/* A float32 image to encode; mirrored by picamcal.ckernel._EncodeJob. */
typedef struct {
    const float *image;               /* (height, width, 3) */
    int64_t height, width;
    picamcal_output output;
    int64_t block_rows;
    int64_t threads;
} picamcal_encode_job;

/* For picamcal.ckernel to check that its mirrors of the structs have the same sizes. */
size_t picamcal_job_size(void) { return sizeof(picamcal_job); }
size_t picamcal_encode_job_size(void) { return sizeof(picamcal_encode_job); }

static const float F05 = 0.5f, F15 = 1.5f, F2 = 2.0f, F4 = 4.0f, F5 = 5.0f, F6 = 6.0f, EIGHTH = 0.125f;
static const float CODE_MAX = 65535.0f;

static inline vec8 splat(float c) { return (vec8){c, c, c, c, c, c, c, c}; }

/* ------------------------------------------------------------------------------------------------- sRGB codes */

/* linear sRGB of channel p: clip((m0 r + m1 g) + m2 b, 0, 1), NaN as 0 (it fails "> 0"), as
 * picamcal.kernels.encode_table. */
static inline vec8 srgb_linear(const float *m, int p, vec8 r, vec8 g, vec8 b) {
    vec8 v = (m[3 * p] * r + m[3 * p + 1] * g) + m[3 * p + 2] * b;
    v = (vec8)((ivec8)v & (ivec8)(v > splat(0.0f)));
    const ivec8 over = (ivec8)(v > splat(1.0f));
    return (vec8)(((ivec8)v & ~over) | ((ivec8)splat(1.0f) & over));
}

/* 8 values from p at a step of `step` floats, or the n < 8 left, then zeros. */
static inline __attribute__((always_inline)) vec8 load8(const float *p, const int64_t step, const int64_t n) {
    if (step == 1 && n >= LANES) {
        return *(const vec8 *)p;
    }
    vec8 v = splat(0.0f);
    for (int64_t l = 0; l < LANES && l < n; l++) {
        v[l] = p[step * l];
    }
    return v;
}

/* n pixels' sRGB codes (n <= CHUNK), interleaved into dst (uint8 or uint16), as picamcal.kernels.encode_table:
 * linear sRGB and its cell in vectors into planes, then the table looked up pixel by pixel (a gather instruction
 * took longer than the loads it stands for, on the machines measured). */
static inline __attribute__((always_inline)) void write_srgb(const picamcal_output *o, int64_t first,
                                                             const float *red, const float *green,
                                                             const float *blue, const int64_t step, const int64_t n) {
    float linear[3][CHUNK + LANES];
    int32_t cell[3][CHUNK + LANES];
    const float cells = (float)o->cells;
    for (int64_t x = 0; x < n; x += LANES) {
        const int64_t left = n - x;
        vec8 r, g, b;
        if (step == 3 && left >= LANES) { /* an interleaved image: 8 pixels' 24 values in 3 vectors, split */
            const vec8 v0 = *(const vec8 *)(red + 3 * x), v1 = *(const vec8 *)(red + 3 * x + 8);
            const vec8 v2 = *(const vec8 *)(red + 3 * x + 16);
            r = SHUFFLE(SHUFFLE(v0, v1, 0, 3, 6, 9, 12, 15, 0, 0), v2, 0, 1, 2, 3, 4, 5, 10, 13);
            g = SHUFFLE(SHUFFLE(v0, v1, 1, 4, 7, 10, 13, 0, 0, 0), v2, 0, 1, 2, 3, 4, 8, 11, 14);
            b = SHUFFLE(SHUFFLE(v0, v1, 2, 5, 8, 11, 14, 0, 0, 0), v2, 0, 1, 2, 3, 4, 9, 12, 15);
        } else {
            r = load8(red + step * x, step, left), g = load8(green + step * x, step, left);
            b = load8(blue + step * x, step, left);
        }
        for (int p = 0; p < 3; p++) {
            const vec8 v = srgb_linear(o->matrix, p, r, g, b);
            *(vec8 *)(linear[p] + x) = v;
            *(ivec8 *)(cell[p] + x) = __builtin_convertvector(v * cells, ivec8); /* exact: cells is a power of 2 */
        }
    }
    const float *restrict inside = o->inside;
    if (o->kind == WRITE_SRGB8) {
        const uint8_t *restrict base = o->base;
        uint8_t *restrict dst = (uint8_t *)o->out + 3 * first;
        for (int64_t x = 0; x < n; x++) {
            for (int p = 0; p < 3; p++) {
                const int32_t c = cell[p][x];
                dst[3 * x + p] = (uint8_t)(base[c] + (linear[p][x] >= inside[c]));
            }
        }
    } else {
        const uint16_t *restrict base = o->base;
        uint16_t *restrict dst = (uint16_t *)o->out + 3 * first;
        for (int64_t x = 0; x < n; x++) {
            for (int p = 0; p < 3; p++) {
                const int32_t c = cell[p][x];
                dst[3 * x + p] = (uint16_t)(base[c] + (linear[p][x] >= inside[c]));
            }
        }
    }
}

/* ------------------------------------------------------------------------------------------------- writing */

/* As picamcal.kernels.encode_codes: NaN and negatives fail "> 0" and give 0; rintf rounds half to even in the
 * default rounding mode, as numpy's rint. */
static inline uint16_t scaled_code(float value, float scale) {
    float v = value * scale;
    v = v > 0.0f ? v : 0.0f;
    v = v < CODE_MAX ? v : CODE_MAX;
    return (uint16_t)rintf(v);
}

/* n pixels from three channel arrays read at a step of `step` floats (1: planar rows, 3: an interleaved image),
 * written interleaved from pixel `first` of the output. Inlined with step a constant, for the loops to vectorise. */
static inline __attribute__((always_inline)) void write_pixels(const picamcal_output *o, int64_t first,
                                                               const float *restrict red,
                                                               const float *restrict green,
                                                               const float *restrict blue, const int64_t step,
                                                               const int64_t n) {
    if (o->kind == WRITE_FLOATS) {
        float *restrict dst = (float *)o->out + 3 * first;
        for (int64_t x = 0; x < n; x++) {
            dst[3 * x] = red[step * x];
            dst[3 * x + 1] = green[step * x];
            dst[3 * x + 2] = blue[step * x];
        }
    } else if (o->kind == WRITE_SCALED) {
        uint16_t *restrict dst = (uint16_t *)o->out + 3 * first;
        const float scale = o->scale;
        for (int64_t x = 0; x < n; x++) {
            dst[3 * x] = scaled_code(red[step * x], scale);
            dst[3 * x + 1] = scaled_code(green[step * x], scale);
            dst[3 * x + 2] = scaled_code(blue[step * x], scale);
        }
    } else {
        for (int64_t x = 0; x < n; x += CHUNK) {
            const int64_t count = n - x < CHUNK ? n - x : CHUNK;
            write_srgb(o, first + x, red + step * x, green + step * x, blue + step * x, step, count);
        }
    }
}

/* ---------------------------------------------------------------------------------------------- correcting */

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

/* Malvar-He-Cutler on the flat rows y - 2 .. y + 2 (r[0] .. r[4], two padded planes each of `stride` floats, from
 * the chunk's first pair on) of a row whose pixel 2j + gx is green and 2j + nx its red or blue ("own"), for `pairs`
 * pairs, into the chunk's green, own and other colour. Inlined with gx a constant, for the loop to vectorise. */
static inline __attribute__((always_inline)) void demosaic_pairs(float *const r[5], const int64_t gx,
                                                                  const int64_t stride, const int64_t pairs,
                                                                  float *restrict green, float *restrict own,
                                                                  float *restrict other) {
    const int64_t nx = 1 - gx;
    const float *restrict g0 = r[0] + gx * stride, *restrict g1 = r[1] + gx * stride, *restrict g2 = r[2] + gx * stride;
    const float *restrict g3 = r[3] + gx * stride, *restrict g4 = r[4] + gx * stride;
    const float *restrict n0 = r[0] + nx * stride, *restrict n1 = r[1] + nx * stride, *restrict n2 = r[2] + nx * stride;
    const float *restrict n3 = r[3] + nx * stride, *restrict n4 = r[4] + nx * stride;
    for (int64_t j = 0; j < pairs; j++) {
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

/* Malvar-He-Cutler at row y, columns x0 .. x0 + n (x0 and n even), into the planar chunk rgb (3, PLANE). */
static void demosaic_chunk(float *const r[5], int64_t y, const picamcal_job *job, int64_t x0, int64_t n,
                           float *restrict rgb) {
    const int64_t sy = y & 1, stride = job->width / 2 + 2;
    const int64_t c_even = job->channels[2 * sy], c_odd = job->channels[2 * sy + 1];
    const int64_t colour = c_even == 1 ? c_odd : c_even;
    float *green = rgb + PLANE, *own = rgb + colour * PLANE, *other = rgb + (2 - colour) * PLANE;
    float *const from[5] = {r[0] + x0 / 2, r[1] + x0 / 2, r[2] + x0 / 2, r[3] + x0 / 2, r[4] + x0 / 2};
    if (c_even == 1) {
        demosaic_pairs(from, 0, stride, n / 2, green, own, other);
    } else {
        demosaic_pairs(from, 1, stride, n / 2, green, own, other);
    }
}

/* The matrix field's coefficients at row y, evaluated along y: along (9, matrix_nx). */
static void matrix_along_y(const picamcal_job *job, int64_t y, float *restrict along) {
    const int64_t height = job->height, nx = job->matrix_nx;
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
}

/* The matrix field on `vectors` whole vectors of pixels from a run's first (along: the run's first coefficients,
 * elements nx apart; u0: its first column weights, the 4 weights `width` apart; red, green, blue and d: the
 * planar chunk from its first column, channels PLANE apart); when `two`, also a second row's (along2, red2, d2),
 * the column weights read once for both (4 % less time). Inlined with `vectors` and `two` constants, for the usual
 * run lengths to be straight-line code. */
static inline __attribute__((always_inline)) void unmix_vectors(const int64_t vectors, const int two,
                                                                const float *along, const float *along2,
                                                                const int64_t nx, const float *u0,
                                                                const int64_t width, const float *red,
                                                                const float *red2, float *d, float *d2) {
    const float *u1 = u0 + width, *u2 = u1 + width, *u3 = u2 + width;
    for (int p = 0; p < 3; p++) {
        const float *ap0 = along + (3 * p) * nx, *ap1 = ap0 + nx, *ap2 = ap1 + nx;
        const float *bp0 = two ? along2 + (3 * p) * nx : ap0, *bp1 = bp0 + nx, *bp2 = bp1 + nx;
        for (int64_t v = 0; v < vectors * LANES; v += LANES) {
            const vec8 v0 = *(const vec8 *)(u0 + v), v1 = *(const vec8 *)(u1 + v);
            const vec8 v2 = *(const vec8 *)(u2 + v), v3 = *(const vec8 *)(u3 + v);
            const vec8 m0 = ((v0 * ap0[0] + v1 * ap0[1]) + v2 * ap0[2]) + v3 * ap0[3];
            const vec8 m1 = ((v0 * ap1[0] + v1 * ap1[1]) + v2 * ap1[2]) + v3 * ap1[3];
            const vec8 m2 = ((v0 * ap2[0] + v1 * ap2[1]) + v2 * ap2[2]) + v3 * ap2[3];
            *(vec8 *)(d + p * PLANE + v) = (m0 * *(const vec8 *)(red + v) + m1 * *(const vec8 *)(red + PLANE + v)) +
                                           m2 * *(const vec8 *)(red + 2 * PLANE + v);
            if (two) {
                const vec8 n0 = ((v0 * bp0[0] + v1 * bp0[1]) + v2 * bp0[2]) + v3 * bp0[3];
                const vec8 n1 = ((v0 * bp1[0] + v1 * bp1[1]) + v2 * bp1[2]) + v3 * bp1[3];
                const vec8 n2 = ((v0 * bp2[0] + v1 * bp2[1]) + v2 * bp2[2]) + v3 * bp2[3];
                *(vec8 *)(d2 + p * PLANE + v) =
                    (n0 * *(const vec8 *)(red2 + v) + n1 * *(const vec8 *)(red2 + PLANE + v)) +
                    n2 * *(const vec8 *)(red2 + 2 * PLANE + v);
            }
        }
    }
}

/* The matrix field on columns x1 .. x2 of one run, pixel by pixel (along: the run's first coefficients; rgb and
 * mixed: the planar chunk from column x0): the end of a row, where whole vectors would read the weights past it. */
static void unmix_pixels(const picamcal_job *job, const float *along, int64_t x0, int64_t x1, int64_t x2,
                         const float *restrict rgb, float *restrict mixed) {
    const int64_t width = job->width, nx = job->matrix_nx;
    const float *restrict u0 = job->matrix_col_weights, *restrict u1 = u0 + width;
    const float *restrict u2 = u1 + width, *restrict u3 = u2 + width;
    const float *restrict red = rgb - x0, *restrict green = red + PLANE, *restrict blue = green + PLANE;
    for (int p = 0; p < 3; p++) {
        const float *ap0 = along + (3 * p) * nx, *ap1 = ap0 + nx, *ap2 = ap1 + nx;
        const float a00 = ap0[0], a10 = ap0[1], a20 = ap0[2], a30 = ap0[3];
        const float a01 = ap1[0], a11 = ap1[1], a21 = ap1[2], a31 = ap1[3];
        const float a02 = ap2[0], a12 = ap2[1], a22 = ap2[2], a32 = ap2[3];
        float *restrict dp = mixed + p * PLANE - x0;
        for (int64_t x = x1; x < x2; x++) {
            const float m0 = ((u0[x] * a00 + u1[x] * a10) + u2[x] * a20) + u3[x] * a30;
            const float m1 = ((u0[x] * a01 + u1[x] * a11) + u2[x] * a21) + u3[x] * a31;
            const float m2 = ((u0[x] * a02 + u1[x] * a12) + u2[x] * a22) + u3[x] * a32;
            dp[x] = (m0 * red[x] + m1 * green[x]) + m2 * blue[x];
        }
    }
}

/* The matrix field (along: its coefficients at this row) applied to the planar chunk rgb of columns x0 .. x0 + n,
 * into mixed (3, PLANE), and when `two` the same for a second row (along2, rgb2, mixed2); run by run (the pixels
 * between two knots share 4 coefficients), from run *run on, which is left at the run holding the chunk's last
 * column. A run is done in whole vectors from its first pixel: the lanes past its end are written over by the next
 * run's, or fall in the chunk's padding; only at the end of the row is the rest done pixel by pixel. Inlined with
 * `two` a constant. */
static inline __attribute__((always_inline)) void unmix_chunk(const picamcal_job *job, const int two,
                                                              const float *along, const float *along2, int64_t x0,
                                                              int64_t n, int64_t *run, const float *rgb,
                                                              const float *rgb2, float *mixed, float *mixed2) {
    const int64_t width = job->width, nx = job->matrix_nx, x_end = x0 + n;
    for (int64_t r = *run; r < job->n_runs; r++) {
        const int64_t start = (int64_t)job->matrix_runs[r], end = (int64_t)job->matrix_runs[r + 1];
        if (start >= x_end) {
            break;
        }
        *run = r;
        const int64_t x1 = start > x0 ? start : x0, x2 = end < x_end ? end : x_end;
        if (x1 >= x2) {
            continue; /* before the chunk, or padding (runs of another parity's length): first[x1] may lie past the row */
        }
        const int64_t k = job->matrix_col_first[x1];
        const float *a = along + k, *b = two ? along2 + k : a, *u = job->matrix_col_weights + x1;
        const float *from = rgb + x1 - x0, *from2 = two ? rgb2 + x1 - x0 : from;
        float *d = mixed + x1 - x0, *d2 = two ? mixed2 + x1 - x0 : d;
        const int64_t vectors = (x2 - x1 + LANES - 1) / LANES;
        if (x1 + vectors * LANES > width) {
            unmix_pixels(job, a, x0, x1, x2, rgb, mixed);
            if (two) {
                unmix_pixels(job, b, x0, x1, x2, rgb2, mixed2);
            }
            continue;
        }
        switch (vectors) {
        case 1:
            unmix_vectors(1, two, a, b, nx, u, width, from, from2, d, d2);
            break;
        case 2:
            unmix_vectors(2, two, a, b, nx, u, width, from, from2, d, d2);
            break;
        case 3:
            unmix_vectors(3, two, a, b, nx, u, width, from, from2, d, d2);
            break;
        case 4:
            unmix_vectors(4, two, a, b, nx, u, width, from, from2, d, d2);
            break;
        default:
            unmix_vectors(vectors, two, a, b, nx, u, width, from, from2, d, d2);
        }
    }
}

/* ----------------------------------------------------------------------------------------------- threading */

typedef struct {
    const void *job;
    int64_t n_blocks;
    atomic_llong next;    /* the next block to hand out */
    atomic_llong counted; /* mosaic samples at or above the clip level, of the blocks done */
} shared_work;

/* Run `work` on `threads` threads (the calling one among them) until the blocks are handed out. 0 on success;
 * -1 when no thread could allocate its rows (out of memory), in which case the output is incomplete. */
static int run_threads(void *(*work)(void *), const void *job, int64_t height, int64_t block_rows, int64_t threads,
                       int64_t *counted) {
    shared_work shared = {job, (height + block_rows - 1) / block_rows, 0, 0};
    threads = threads < shared.n_blocks ? threads : shared.n_blocks;
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
    *counted = atomic_load(&shared.counted);
    return atomic_load(&shared.next) >= shared.n_blocks ? 0 : -1;
}

/* The clipped samples of mosaic row y (read two rows ago: in the cache). */
static inline int64_t clipped_in_row(const picamcal_job *job, int64_t y, uint16_t clip_level) {
    const uint16_t *restrict raw = job->bayer + y * job->width;
    int64_t clipped = 0;
    for (int64_t x = 0; x < job->width; x++) {
        clipped += raw[x] >= clip_level;
    }
    return clipped;
}

/* The 5 flat rows around row y in the 6-row ring. */
static inline void ring_rows(float *ring, int64_t y, int64_t stride, float *rows[5]) {
    for (int k = 0; k < 5; k++) {
        rows[k] = ring + ((y - 2 + k + 6) % 6) * 2 * stride;
    }
}

/* One correcting thread: take blocks until none is left. A thread that cannot allocate its rows takes none. */
static void *correct_blocks(void *arg) {
    shared_work *shared = arg;
    const picamcal_job *job = shared->job;
    const int64_t width = job->width, height = job->height, stride = job->width / 2 + 2;
    const int64_t ring_size = 6 * 2 * stride;
    float *scratch = calloc((size_t)(ring_size + 12 * PLANE + 18 * (job->matrix_nx + 1)), sizeof(float));
    if (!scratch) {
        return NULL;
    }
    float *ring = scratch, *rgb = ring + ring_size, *rgb2 = rgb + 3 * PLANE, *mixed = rgb2 + 3 * PLANE;
    float *mixed2 = mixed + 3 * PLANE, *along = mixed2 + 3 * PLANE, *along2 = along + 9 * (job->matrix_nx + 1);
    const float *result = job->matrices ? mixed : rgb, *result2 = job->matrices ? mixed2 : rgb2;
    const int count = job->clip_level <= 65535; /* a level past every code counts nothing */
    const uint16_t clip_level = (uint16_t)(count ? job->clip_level : 0);
    int64_t clipped = 0;
    for (;;) {
        const int64_t block = atomic_fetch_add(&shared->next, 1);
        if (block >= shared->n_blocks) {
            break;
        }
        const int64_t y0 = block * job->block_rows;
        const int64_t y1 = y0 + job->block_rows < height ? y0 + job->block_rows : height;
        /* Flat-field row r into the 6-row ring (rows beyond the image mirrored); then, once rows y - 2 .. y + 3 are
         * all in, demosaic, unmix and write rows y and y + 1 together (the column weights read once for both), or
         * the block's last row alone. */
        int64_t y = y0;
        for (int64_t r = y0 - 2; r < y1 + 2; r++) {
            const int64_t source = r < 0 ? -r - 1 : (r >= height ? 2 * height - 1 - r : r);
            flat_row(job, source, ring + ((r + 6) % 6) * 2 * stride);
            const int two = y + 1 < y1;
            if (r - 2 < y + two) {
                continue;
            }
            float *rows[5], *rows2[5];
            ring_rows(ring, y, stride, rows);
            ring_rows(ring, y + 1, stride, rows2);
            clipped += count ? clipped_in_row(job, y, clip_level) : 0;
            clipped += count && two ? clipped_in_row(job, y + 1, clip_level) : 0;
            int64_t run = 0;
            if (job->matrices) {
                matrix_along_y(job, y, along);
                if (two) {
                    matrix_along_y(job, y + 1, along2);
                }
            }
            for (int64_t x0 = 0; x0 < width; x0 += CHUNK) {
                const int64_t n = width - x0 < CHUNK ? width - x0 : CHUNK;
                demosaic_chunk(rows, y, job, x0, n, rgb);
                if (two) {
                    demosaic_chunk(rows2, y + 1, job, x0, n, rgb2);
                }
                if (job->matrices) {
                    if (two) {
                        unmix_chunk(job, 1, along, along2, x0, n, &run, rgb, rgb2, mixed, mixed2);
                    } else {
                        unmix_chunk(job, 0, along, NULL, x0, n, &run, rgb, NULL, mixed, NULL);
                    }
                }
                write_pixels(&job->output, y * width + x0, result, result + PLANE, result + 2 * PLANE, 1, n);
                if (two) {
                    write_pixels(&job->output, (y + 1) * width + x0, result2, result2 + PLANE, result2 + 2 * PLANE,
                                 1, n);
                }
            }
            y += 1 + two;
        }
    }
    free(scratch);
    atomic_fetch_add(&shared->counted, clipped);
    return NULL;
}

/* Correct the frame with job->threads threads (the calling one among them), and count the mosaic's samples at or
 * above job->clip_level into job->clipped: 0, or -1 when out of memory. */
int picamcal_correct(picamcal_job *job) {
    return run_threads(correct_blocks, job, job->height, job->block_rows, job->threads, &job->clipped);
}

/* ------------------------------------------------------------------------------------------------ encoding */

static void *encode_blocks(void *arg) {
    shared_work *shared = arg;
    const picamcal_encode_job *job = shared->job;
    const int64_t width = job->width;
    for (;;) {
        const int64_t block = atomic_fetch_add(&shared->next, 1);
        if (block >= shared->n_blocks) {
            break;
        }
        const int64_t y0 = block * job->block_rows;
        const int64_t y1 = y0 + job->block_rows < job->height ? y0 + job->block_rows : job->height;
        for (int64_t y = y0; y < y1; y++) {
            const float *row = job->image + y * 3 * width;
            write_pixels(&job->output, y * width, row, row + 1, row + 2, 3, width);
        }
    }
    return NULL;
}

/* Encode a float32 (height, width, 3) image as job->output says, on job->threads threads: 0. */
int picamcal_encode(const picamcal_encode_job *job) {
    int64_t counted;
    return run_threads(encode_blocks, job, job->height, job->block_rows, job->threads, &counted);
}
