// Mitsuba 3's Embree on other kernels than its CPU's best: a stand-in's tool for bench/forward.py
// (--llvm-target with an AVX2 CPU). Mitsuba makes its Embree device itself (its Embree's API lives
// in the `mitsuba` namespace) and takes no setting for Embree's instruction set; loaded into the
// process with RTLD_GLOBAL before Mitsuba, this library's definition of that function is the one
// Mitsuba calls, and it calls Mitsuba's own with the settings of $IR_BENCH_EMBREE_CONFIG appended
// (e.g. "isa=avx2"). invrender's Embree takes the same settings from $INVRENDER_EMBREE_CONFIG.
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>

typedef void* (*NewDevice)(const char*);

// mitsuba::rtcNewDevice(const char*), as its caller's own Embree defines it
void* _ZN7mitsuba12rtcNewDeviceEPKc(const char* config) {
    static const char name[] = "_ZN7mitsuba12rtcNewDeviceEPKc";
    Dl_info caller;
    void* library = dladdr(__builtin_return_address(0), &caller) ? dlopen(caller.dli_fname, RTLD_NOLOAD | RTLD_LAZY) : NULL;
    NewDevice own = library ? (NewDevice)dlsym(library, name) : NULL;  // searched in the caller's dependencies only
    if (!own) {
        fprintf(stderr, "embree_isa: no %s beside its caller\n", name);
        abort();
    }
    const char* extra = getenv("IR_BENCH_EMBREE_CONFIG");
    char settings[1024];
    snprintf(settings, sizeof settings, "%s%s%s", config ? config : "", config && *config && extra && *extra ? "," : "", extra ? extra : "");
    return own(settings);
}
