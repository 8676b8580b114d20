/* embree_isa.c - caps the ISA of the Embree that Mitsuba 3 bundles, for
 * bench/peer/mitsuba_peer.py --isa: measuring the peer as an AVX2-only
 * host runs it, on a host with AVX-512 (issue 23 asks for both ISAs).
 *
 * Mitsuba creates its Embree device with a config string of its own and
 * its Embree reads no config file, so this library, preloaded
 * (LD_PRELOAD), stands in for that Embree's rtcNewDevice (built in
 * namespace mitsuba, hence the C++ name), appends $VB_EMBREE_ISA
 * ("isa=avx2") to the config and calls the real one in $VB_EMBREE_LIB.
 * It sets VB_EMBREE_ISA_APPLIED to the config it passed, so the script
 * can check that the cap took effect. Benchmark tooling, not the product. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>

typedef void *embree_device_t;
typedef embree_device_t (*new_device_fn)(const char *config);

#define MITSUBA_RTC_NEW_DEVICE "_ZN7mitsuba12rtcNewDeviceEPKc"

embree_device_t embree_isa_new_device(const char *config) __asm__(MITSUBA_RTC_NEW_DEVICE);

embree_device_t embree_isa_new_device(const char *config)
{
    const char *lib = getenv("VB_EMBREE_LIB"), *isa = getenv("VB_EMBREE_ISA");
    void *handle = lib ? dlopen(lib, RTLD_LAZY | RTLD_NOLOAD) : NULL;
    new_device_fn real = NULL;
    if (handle)
        *(void **)&real = dlsym(handle, MITSUBA_RTC_NEW_DEVICE);
    if (!real) {
        fprintf(stderr, "embree_isa: no %s in %s\n", MITSUBA_RTC_NEW_DEVICE, lib ? lib : "(unset)");
        return NULL;
    }
    char capped[1024];
    snprintf(capped, sizeof capped, "%s%s%s", config ? config : "",
             config && *config && isa && *isa ? "," : "", isa ? isa : "");
    setenv("VB_EMBREE_ISA_APPLIED", capped, 1);
    return real(capped);
}
