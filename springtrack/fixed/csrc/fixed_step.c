/* Integer-only tracker step: the fixed-point translation of springtrack/kernel/kernel.pyx, for
 * 32-bit cores.
 *
 * Equations cite Valeiras et al. 2015; [ref] names the function of
 * springtrack/reference.py a block mirrors.  Q formats are listed in fixed_step.h and
 * justified, with their error bounds, in docs/fixed_point.md.  No floating-point type
 * appears in this file: it compiles with `gcc -mgeneral-regs-only`, and every product is
 * a 32 x 32 -> 64-bit one (smul, umul below).
 */
#include "fixed_step.h"
#include "fixed_tables.h"
#include "../../csrc/sampling.h"

#define ONE_Q30 ((int64_t)1 << 30)
#define RHO_Q30 1063004406u        /* 0.99 (reference.RHO_MAX), Q.30 */
#define RHO2_Q30 1052374362u       /* 0.99^2, Q.30 */
#define PI_Q28 843314857u          /* pi, Q.28 */
#define PI_Q29 1686629713          /* pi, Q.29: binary angle * PI_Q29 / 2^30 = rad Q.30 */
#define SMALL_ANGLE ((int64_t)42722830)   /* 2^-4 rad as a binary angle */
#define ACT_MAX ((int64_t)1 << 61) /* activity saturates at 2^29 */
#define E_MAX ((int64_t)1 << 61)   /* an energy (Q.40) saturates at 2^21 px^2 */
#define D2_SAT 0xffffffffu         /* d^2 >= 32: beyond any gate */
/* A 64-bit host does a few steps in 64-bit words, where a 32-bit core uses two 32-bit ones
   (the candidate mask, d^2's final shift, the 64 / 32 divisions): the same integers
   either way, each in the target's natural word. */
#define FX_WORD64 (UINTPTR_MAX > 0xffffffffu)

/* The unit, one part per job, in the order of its declarations (a part calls what the
   parts before it define; the two forward declarations are in fixed_tracker.c and
   fixed_spring.c). */
#include "fixed_arith.c"
#include "fixed_motion.c"
#include "fixed_index.c"
#include "fixed_tracker.c"
#include "fixed_set.c"
#include "fixed_spring.c"
#include "fixed_frame.c"
#include "fixed_update.c"
#include "fixed_load.c"
#include "fixed_move.c"
