/* Bare-metal start for a Cortex-M4F under QEMU (mps2-an386) with semihosting: the vector table,
   the FPU switched on, .bss cleared, newlib's semihosted I/O opened, then the program's main. */
#include <stdlib.h>

extern unsigned int __bss_start__, __bss_end__, __stack_top__;
extern void initialise_monitor_handles(void);
extern int bfc_main(int argc, char **argv);

void reset(void);
static void fault(void) { exit(99); }

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))&__stack_top__, reset, fault, fault, fault, fault, fault,
};

void reset(void)
{
    static char *argv[] = {"bfc", "rows.bin", "out.bin", 0};
    unsigned int *p;
    *(volatile unsigned int *)0xE000ED88u |= 0xFu << 20; /* CPACR: CP10 and CP11, full access */
    __asm volatile("dsb\n\tisb");
    for (p = &__bss_start__; p < &__bss_end__; ++p) *p = 0;
    initialise_monitor_handles();
    exit(bfc_main(3, argv));
}

void _init(void) {} /* newlib's constructors and destructors: none here */
void _fini(void) {}
