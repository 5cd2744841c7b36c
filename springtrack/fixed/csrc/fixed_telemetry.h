/* TELEMETRY tracker records straight from the fixed-point state (integer-only).
 *
 * The layout is springtrack/wire.py's TELE_TRACKER (docs/protocol.md), 8 bytes per tracker,
 * little-endian:
 *   u16 x, y   position in 1/16 px: (m + 2^27) >> 28 of the Q.32 state, clamped to
 *              0 .. 0x7FFF; x bit 15 = active, y bit 15 = sensitive
 *   u8  sx, sy standard deviation in 1/4 px: isqrt(s_Q40) is sigma in Q.20, rounded >> 18
 *   i8  rho    correlation x 127: round(127 sxy / (sigma_x sigma_y)), one division
 *   u8  act    round(16 log2(1 + A)): leading-bit position + a 16-entry threshold table
 * so a firmware running this kernel converts its state once, at telemetry rate, and never
 * through floating point.  Compiles with gcc -mgeneral-regs-only like fixed_step.c
 * (tests/test_springtrack/fixed/test_fixed_integer_only.py).  The scales are checked against wire.py when _fixed is
 * imported; tests/test_springtrack/fixed/test_fixed_telemetry.py compares the codes with wire.quantise_trackers
 * (the quantiser of the float state) of the float view of the same state.
 */
#ifndef SPRINGTRACK_FIXED_TELEMETRY_H
#define SPRINGTRACK_FIXED_TELEMETRY_H

#include <stdint.h>
#include "fixed_step.h"

#define FX_TELE_RECORD 8          /* bytes per tracker */
#define FX_TELE_POS_SHIFT 28      /* Q.32 -> 1/16 px */
#define FX_TELE_SIGMA_SHIFT 18    /* Q.20 -> 1/4 px */
#define FX_TELE_RHO_SCALE 127
#define FX_TELE_ACT_STEPS 16      /* activity code steps per octave */

/* records of all s->n trackers at event time t into out[s->n * FX_TELE_RECORD] */
void fx_tele_records(const fx_state *s, int64_t t, uint8_t *out);

#endif
