/* The board layer of the firmware image: the host link's UART, polled, for the boards of
 * springtrack/mcu/boards.py (which passes BOARD_UART_*, LINK_UART and BOARD_CLOCK_HZ).
 *   uart_init()     clocks and pins for the UART, 8N1 at LINK_BAUD, transmitter and
 *                   receiver on
 *   uart_getc()     the next received byte, or -1 if none is waiting
 *   uart_putc(c)    send one byte (waits while the transmit register is full)
 *   board_halt()    end the program: semihosting SYS_EXIT under QEMU (springtrack mcu
 *                   run enables it), a halted core on a board without a debugger
 * The receiver is polled by the main loop between event batches; QEMU holds the host's
 * bytes back while the receive register is full, so none is lost here (a real board
 * would add an interrupt-fed ring buffer, or hardware flow control). */
#ifndef SPRINGTRACK_BOARD_H
#define SPRINGTRACK_BOARD_H

#include <stdint.h>

#define REG(a) (*(volatile uint32_t *)(a))
#ifndef LINK_BAUD
#define LINK_BAUD 115200u
#endif

#if defined(BOARD_UART_STM32)
/* STM32F4 USART (RM0090 30.6): SR +0 (RXNE bit 5, TXE bit 7), DR +4, BRR +8, CR1 +0xC (UE
   bit 13, TE bit 3, RE bit 2).  USART1 on PA9 (TX) / PA10 (RX), alternate function 7; the
   core runs on its reset clock (HSI, BOARD_CLOCK_HZ), APB2 undivided */
#define RCC_AHB1ENR 0x40023830u
#define RCC_APB2ENR 0x40023844u
#define GPIOA 0x40020000u
static inline void uart_init(void)
{
    REG(RCC_AHB1ENR) |= 1u << 0;                            /* GPIOA clock */
    REG(RCC_APB2ENR) |= 1u << 4;                            /* USART1 clock */
    REG(GPIOA + 0x00) = (REG(GPIOA + 0x00) & ~(0xFu << 18)) | (0xAu << 18);   /* PA9/10 AF */
    REG(GPIOA + 0x24) = (REG(GPIOA + 0x24) & ~0xFF0u) | 0x770u;              /* AF7 */
    REG(LINK_UART + 0x08) = (BOARD_CLOCK_HZ + LINK_BAUD / 2) / LINK_BAUD;     /* over 16 */
    REG(LINK_UART + 0x0C) = (1u << 13) | (1u << 3) | (1u << 2);
}
static inline int uart_getc(void)
{
    if (REG(LINK_UART + 0x00) & (1u << 5))
        return (int)(REG(LINK_UART + 0x04) & 0xFFu);
    return -1;
}
static inline void uart_putc(uint8_t c)
{
    while (!(REG(LINK_UART + 0x00) & (1u << 7)))
        ;
    REG(LINK_UART + 0x04) = c;
}
#elif defined(BOARD_UART_CMSDK)
/* Arm CMSDK APB UART (DDI 0479, 4.3): DATA +0, STATE +4 (TX full bit 0, RX full bit 1),
   CTRL +8 (TX enable bit 0, RX enable bit 1), BAUDDIV +0x10 (>= 16) */
static inline void uart_init(void)
{
    REG(LINK_UART + 0x10) = BOARD_CLOCK_HZ / LINK_BAUD;
    REG(LINK_UART + 0x08) = 3u;
}
static inline int uart_getc(void)
{
    if (REG(LINK_UART + 0x04) & 2u)
        return (int)(REG(LINK_UART + 0x00) & 0xFFu);
    return -1;
}
static inline void uart_putc(uint8_t c)
{
    while (REG(LINK_UART + 0x04) & 1u)
        ;
    REG(LINK_UART + 0x00) = c;
}
#else
#error "no board UART: build through springtrack/mcu/image.py (BOARD_UART_STM32 or _CMSDK)"
#endif

/* ARM semihosting SYS_EXIT (0x18) with ADP_Stopped_ApplicationExit: QEMU ends */
static inline void board_halt(void)
{
    register uint32_t r0 __asm__("r0") = 0x18u;
    register uint32_t r1 __asm__("r1") = 0x20026u;
    __asm__ volatile("bkpt 0xAB" : : "r"(r0), "r"(r1) : "memory");
    for (;;)
        __asm__ volatile("wfi");
}

/* a free-running count for nonces and sequence numbers: the SysTick counter (ARMv7-M
   B3.3), started by startup.c */
static inline uint32_t board_ticks(void)
{
    return REG(0xE000E018u);
}

#endif
