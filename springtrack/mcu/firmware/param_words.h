/* The tracker parameters on the core (params.c's PARAM_SET by name): their checks, as
 * springtrack.params.check, Params, springtrack.limits.check_params and the fixed kernel
 * make them, with the same NACK codes; and their kernel words, as
 * springtrack.fixed.q.params_words computes them from the values, in integers.
 *   param_lookup(name, n)            the parameter's index, -1 if none has that name
 *   param_choice(k, text, n)         the index of a str parameter's choice, -1 if none
 *   param_check_value(k, tag, v...)  one value (wire type tag and bytes) into `v`
 *   param_check_set(v, nc, why)      the whole set for a model of nc connections
 *   param_words(v, nc, w, tables)    its Q_PARAMS_WORDS words (a checked set); tables 0:
 *                                    w's activity decay tables kept (the same tau) */
#ifndef SPRINGTRACK_FW_PARAM_WORDS_H
#define SPRINGTRACK_FW_PARAM_WORDS_H

#include <stdint.h>
#include "param_specs.h"
#include "text.h"
#include "xfloat.h"

typedef struct {
    dbits_t f[PARAM_COUNT];            /* a float parameter's value */
    int64_t i[PARAM_COUNT];             /* an int parameter's value, a choice's index */
} values_t;

uint64_t param_rd64(const uint8_t *p);
int param_lookup(const uint8_t *p, uint32_t n);
int param_choice(int k, const uint8_t *p, uint32_t n);
int param_check_value(int k, uint8_t tag, const uint8_t *val, values_t *v, buf_t *w);
int param_check_set(const values_t *v, int32_t nc, buf_t *w);
void param_words(const values_t *v, int32_t nc, int32_t *w, int tables);

#endif
