#pragma once

// Which sanitizer this translation unit is compiled with, as 0/1 macros that
// mean the same under GCC and clang: GCC defines __SANITIZE_ADDRESS__ and
// __SANITIZE_THREAD__, clang 14 only answers __has_feature(...). The ASan
// preset and the TSan preset both build with clang-14 (CMakePresets.json).
//   BP_UNDER_ASAN  AddressSanitizer
//   BP_UNDER_TSAN  ThreadSanitizer

#if defined(__SANITIZE_ADDRESS__)
#define BP_UNDER_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define BP_UNDER_ASAN 1
#endif
#endif
#ifndef BP_UNDER_ASAN
#define BP_UNDER_ASAN 0
#endif

#if defined(__SANITIZE_THREAD__)
#define BP_UNDER_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define BP_UNDER_TSAN 1
#endif
#endif
#ifndef BP_UNDER_TSAN
#define BP_UNDER_TSAN 0
#endif
