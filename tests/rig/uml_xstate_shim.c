/* Preloaded into user-mode Linux by vcan_rig.sh so UML 6.1 runs on hosts with AMX (e.g. Sapphire
 * Rapids): UML restores its processes' FPU state with PTRACE_SETREGSET(NT_X86_XSTATE) and a
 * buffer sized for the XSAVE features enabled at boot (2696 bytes), but the host kernel accepts
 * only a buffer of the full XSAVE size including the dynamically enabled AMX tile state
 * (CPUID.(EAX=0DH,ECX=0):ECX, 11008 bytes here) and fails the call with EFAULT: the guest's init
 * dies with "ptrace set fp regs failed, errno = 14". The shim widens the buffer, the extra
 * components zeroed (their XSTATE_BV bits stay clear, so they load their init state). Every
 * other ptrace request passes through untouched. */
#define _GNU_SOURCE
#include <cpuid.h>
#include <dlfcn.h>
#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/uio.h>

#define NT_X86_XSTATE 0x202

long ptrace(enum __ptrace_request request, ...) {
  static long (*real_ptrace)(enum __ptrace_request, ...);
  if (!real_ptrace) real_ptrace = (long (*)(enum __ptrace_request, ...))dlsym(RTLD_NEXT, "ptrace");
  va_list args;
  va_start(args, request);
  pid_t pid = va_arg(args, pid_t);
  void* addr = va_arg(args, void*);
  void* data = va_arg(args, void*);
  va_end(args);
  if (request == PTRACE_SETREGSET && (long)addr == NT_X86_XSTATE && data) {
    struct iovec* iov = data;
    unsigned eax, ebx, ecx, edx;
    __cpuid_count(0xD, 0, eax, ebx, ecx, edx);
    if (iov->iov_len < ecx) {
      char* wide = calloc(1, ecx);
      if (!wide) {
        errno = ENOMEM;
        return -1;
      }
      memcpy(wide, iov->iov_base, iov->iov_len);
      struct iovec wide_iov = {wide, ecx};
      long result = real_ptrace(request, pid, addr, &wide_iov);
      int saved = errno;
      free(wide);
      errno = saved;
      return result;
    }
  }
  return real_ptrace(request, pid, addr, data);
}
