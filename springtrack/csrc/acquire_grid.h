/* The inner loop of the acquisition's coarse search (springtrack/acquisition/scoring.pyx, score_grid):
 * the score plane of one pose, a weighted sum of shifted rows of per-level score images.
 * Vectorised clones for SSE2 / AVX2 / AVX-512, picked at load time (ST_CLONES). */
#ifndef SPRINGTRACK_ACQUIRE_GRID_H
#define SPRINGTRACK_ACQUIRE_GRID_H

/* for ST_CLONES; its batch functions are not used here */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#include "fastmath.h"
#pragma GCC diagnostic pop

/* plane[y nx + x] = sum_k w[k] levels[lev[k] hw + off[k] + y wp + x] for y < ny, x < nx:
 * the score of each translation cell of one pose (trackers k < n_k). */
ST_CLONES static void acq_pose_plane(const float *restrict levels, const int *restrict off,
                                     const int *restrict lev, const float *restrict w,
                                     int n_k, long hw, int wp, int ny, int nx,
                                     float *restrict plane)
{
    for (int i = 0; i < ny * nx; i++)
        plane[i] = 0.0f;
    for (int k = 0; k < n_k; k++) {
        const float *base = levels + lev[k] * hw + off[k];
        const float wk = w[k];
        for (int y = 0; y < ny; y++) {
            const float *restrict row = base + (long)y * wp;
            float *restrict out = plane + (long)y * nx;
            for (int x = 0; x < nx; x++)
                out[x] += wk * row[x];
        }
    }
}

#endif /* SPRINGTRACK_ACQUIRE_GRID_H */
