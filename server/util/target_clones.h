// OCTO_TARGET_CLONES_AVX2: GCC function multiversioning for hot loops — the function is compiled
// for AVX2 and for the baseline, and the loader picks one for the CPU it runs on.
// Sanitizer runtimes (ThreadSanitizer, AddressSanitizer) crash in the ifunc resolvers this needs,
// so sanitized builds get the baseline version only.
//
// Thread safety: a macro.
#ifndef OCTOSCOPE_UTIL_TARGET_CLONES_H_
#define OCTOSCOPE_UTIL_TARGET_CLONES_H_

#if defined(__SANITIZE_THREAD__) || defined(__SANITIZE_ADDRESS__) || defined(__clang__)
#define OCTO_TARGET_CLONES_AVX2
#else
#define OCTO_TARGET_CLONES_AVX2 __attribute__((target_clones("avx2", "default")))
#endif

#endif  // OCTOSCOPE_UTIL_TARGET_CLONES_H_
