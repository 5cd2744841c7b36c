/* Start-up code of the firmware image: the vector table (ARMv7-M B1.5.3) and the reset
 * handler, which copies initialised data from flash, zeroes .bss, paints the stack (for
 * fw_stack_used(): the deepest it has been, reported by STATS), starts SysTick as a
 * free-running counter and calls fw_main().  No heap, no libc, no floating point: the
 * FPU of a Cortex-M4F/M7 stays off (CPACR untouched). */
#include <stddef.h>
#include <stdint.h>

extern uint32_t __stack_top, __stack_bottom, __data_load, __data_start, __data_end, __bss_start,
    __bss_end;
void fw_main(void);
void reset_handler(void);
uint32_t fw_stack_used(void);

#define STACK_PAINT 0x5AC3A55Au

/* a fault or an unexpected interrupt: stop here (a debugger finds the core in this loop) */
static void fault_handler(void)
{
    for (;;)
        __asm__ volatile("");
}

__attribute__((section(".vectors"), used)) void (*const fw_vectors[16])(void) = {
    (void (*)(void))&__stack_top, reset_handler,
    fault_handler, fault_handler, fault_handler, fault_handler, fault_handler,  /* NMI .. usage */
    0, 0, 0, 0, fault_handler, fault_handler, 0, fault_handler, fault_handler,  /* SVC .. SysTick */
};

void reset_handler(void)
{
    uint32_t *src = &__data_load, *dst = &__data_start;
    while (dst < &__data_end)
        *dst++ = *src++;
    for (dst = &__bss_start; dst < &__bss_end;)
        *dst++ = 0;
    /* the stack below this frame painted, so that fw_stack_used() can find its deepest use */
    for (dst = &__stack_bottom; dst < (uint32_t *)__builtin_frame_address(0) - 16;)
        *dst++ = STACK_PAINT;
    *(volatile uint32_t *)0xE000E014u = 0x00FFFFFFu;       /* SysTick reload: 24 bits */
    *(volatile uint32_t *)0xE000E010u = 5u;                /* core clock, enabled, no IRQ */
    fw_main();
    for (;;)
        __asm__ volatile("");
}

uint32_t fw_stack_used(void)
{
    const uint32_t *p = &__stack_bottom;
    while (p < &__stack_top && *p == STACK_PAINT)
        p++;
    return (uint32_t)((const uint8_t *)&__stack_top - (const uint8_t *)p);
}

/* what the compiler may call for block copies and clears, with no libc to take them from */
void *memcpy(void *d, const void *s, size_t n)
{
    uint8_t *a = d;
    const uint8_t *b = s;
    while (n--)
        *a++ = *b++;
    return d;
}

void *memset(void *d, int c, size_t n)
{
    uint8_t *a = d;
    while (n--)
        *a++ = (uint8_t)c;
    return d;
}
