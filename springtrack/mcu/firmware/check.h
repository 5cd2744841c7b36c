/* Validation of an uploaded words image's model and parameter words against the limits
 * every backend shares (springtrack/limits.py, docs/algorithm.md "Limits"), on the
 * quantised values: what springtrack.fixed.q model_q / params_q produce from a model and parameters
 * within them.  The host checks the same limits before it converts (hostctl); these
 * checks are what a hostile or broken host meets.  Each returns 0 if the words are
 * valid, else the NACK code, with the reason appended to `why`. */
#ifndef SPRINGTRACK_FW_CHECK_H
#define SPRINGTRACK_FW_CHECK_H

#include <stdint.h>
#include "text.h"

int check_model(const int32_t *w, uint32_t nw, uint32_t width, uint32_t height, buf_t *why);
int check_params(const int32_t *w, uint32_t nw, buf_t *why);

#endif
