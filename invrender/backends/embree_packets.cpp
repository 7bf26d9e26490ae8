// Embree's packet queries for the embree intersection backend (invrender/backends/embree_native.py).
//
// A ray batch arrives as flat float32 arrays (origins and unit directions (N, 3), distances (N,));
// each query packs the rays it traces into Embree's structure-of-arrays packets of the device's
// native width (16 rays with AVX-512, 8 with AVX2, else 4: an emulated width costs more a ray; the
// rays it does not trace take no lane) and writes its answers straight into the caller's (torch)
// arrays: closest hits as (t, triangle, u, v) with t = inf and triangle = -1 for a miss, or
// compacted to the rays that hit (with, for paths that ended, rays not traced at all); shadow rays
// as one byte each. A shadow ray whose distance is not
// positive (or NaN) is not traced and answers "not occluded": nothing lies strictly before it.
// A ray that Embree would refuse (a component of its origin or direction NaN, infinite or beyond
// Embree's FLT_LARGE) is not traced either: a miss, not occluded. Embree built with assertions
// (Debian's is) aborts the process on such a lane; the Python side (accel.Intersector) masks these
// rays before the call, and this check keeps the wrapper safe on its own.
//
// Built on first use against the system's Embree 3 (Debian's libembree-dev) and loaded by ctypes,
// which releases the GIL for the call, so Python threads can split a batch. The device takes
// Embree's configuration string (`isa=avx2`: the AVX2 kernels, and packets of 8, on any CPU with AVX2).

#include <embree3/rtcore.h>

#if defined(__SSE__) || defined(__x86_64__)
#include <xmmintrin.h>
#define IR_HAS_MXCSR 1
#endif

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <type_traits>

namespace {

constexpr int kMaxLanes = 16;  // rays per packet at most
constexpr float kRayLimit = 1.844e18f;  // Embree's FLT_LARGE (RayK::valid); accel.RAY_LIMIT

// A batch of rays read through a stride (in floats) per component array: component j of ray i's
// origin is o[j][i * o_lane] (rows (n, 3): o[j] = base + j, o_lane 3; columns (3, n): o[j] = base
// + j n, o_lane 1; or three arrays of their own, o_lane 1).
struct Rays {
    const float* o[3];
    int64_t o_lane;
    const float* d[3];
    int64_t d_lane;
    float origin(int64_t i, int j) const { return o[j][i * o_lane]; }
    float direction(int64_t i, int j) const { return d[j][i * d_lane]; }
};

// Can ray i be traced: every component of its origin and direction finite and within kRayLimit?
inline bool traceable(const Rays& r, int64_t i) {
    bool ok = true;
    for (int j = 0; j < 3; ++j) ok &= std::fabs(r.origin(i, j)) <= kRayLimit && std::fabs(r.direction(i, j)) <= kRayLimit;  // false for NaN
    return ok;
}

struct Accel {
    RTCDevice device;
    RTCScene scene;
    int lanes;  // the packets' width: the widest the device traces natively (16, 8 or 4)
};

// Embree's packet of K rays (16, 8 or 4) and its queries.
template <int K>
struct Packet {
    using Ray = std::conditional_t<K == 16, RTCRay16, std::conditional_t<K == 8, RTCRay8, RTCRay4>>;
    using RayHit = std::conditional_t<K == 16, RTCRayHit16, std::conditional_t<K == 8, RTCRayHit8, RTCRayHit4>>;
    static void intersect(const int* valid, RTCScene s, RTCIntersectContext* c, RayHit* r) {
        if constexpr (K == 16) rtcIntersect16(valid, s, c, r);
        else if constexpr (K == 8) rtcIntersect8(valid, s, c, r);
        else rtcIntersect4(valid, s, c, r);
    }
    static void occluded(const int* valid, RTCScene s, RTCIntersectContext* c, Ray* r) {
        if constexpr (K == 16) rtcOccluded16(valid, s, c, r);
        else if constexpr (K == 8) rtcOccluded8(valid, s, c, r);
        else rtcOccluded4(valid, s, c, r);
    }
};

// f(std::integral_constant<int, K>) for the accel's packet width K.
template <class F>
auto with_lanes(void* accel, F&& f) {
    switch (static_cast<Accel*>(accel)->lanes) {
        case 16: return f(std::integral_constant<int, 16>());
        case 8: return f(std::integral_constant<int, 8>());
        default: return f(std::integral_constant<int, 4>());
    }
}

// Lane k of a packet: ray i of the batch from 0 to tfar.
template <class Ray>
inline void pack(Ray& ray, int k, const Rays& r, int64_t i, float tfar) {
    ray.org_x[k] = r.origin(i, 0), ray.org_y[k] = r.origin(i, 1), ray.org_z[k] = r.origin(i, 2);
    ray.dir_x[k] = r.direction(i, 0), ray.dir_y[k] = r.direction(i, 1), ray.dir_z[k] = r.direction(i, 2);
    ray.tnear[k] = 0.0f, ray.tfar[k] = tfar, ray.time[k] = 0.0f;
    ray.mask[k] = ~0u, ray.id[k] = 0, ray.flags[k] = 0;
}

// A packet's lanes from `lanes` on made finite stand-ins (from the world origin along +z, tfar 0),
// and its valid mask: -1 for the lanes below `lanes`, 0 for the others.
template <int K, class Ray>
inline void close_packet(Ray& ray, int* valid, int lanes) {
    for (int k = 0; k < K; ++k) {
        valid[k] = k < lanes ? -1 : 0;
        if (k < lanes) continue;
        ray.org_x[k] = ray.org_y[k] = ray.org_z[k] = 0.0f;
        ray.dir_x[k] = ray.dir_y[k] = 0.0f, ray.dir_z[k] = 1.0f;
        ray.tnear[k] = 0.0f, ray.tfar[k] = 0.0f, ray.time[k] = 0.0f;
        ray.mask[k] = ~0u, ray.id[k] = 0, ray.flags[k] = 0;
    }
}

// Within a query, denormals flushed to zero (in and out: the MXCSR's FTZ and DAZ bits), as Embree
// asks of the threads that trace; the caller's mode is restored on the way out (torch's
// arithmetic in the same thread keeps IEEE denormals).
#ifdef IR_HAS_MXCSR
struct FlushDenormals {
    unsigned saved = _mm_getcsr();
    FlushDenormals() { _mm_setcsr(saved | 0x8040u); }  // FTZ (bit 15) and DAZ (bit 6)
    ~FlushDenormals() { _mm_setcsr(saved); }
};
#else
struct FlushDenormals {};  // (no MXCSR: another architecture's default mode is kept)
#endif

void say(char* error, int64_t size, const char* what, RTCError code) {
    std::snprintf(error, size_t(size), "Embree: %s (error %d)", what, int(code));
}

// Rays 0 .. n - 1 in packets of K of the ones traced(i) picks, which alone fill the lanes (a packet
// full of traced rays costs less a ray than one with lanes masked off: 20% less for a Cornell
// box's shadow rays, 30% of which are not traced): fill(k, i) puts ray i in lane k, launch(lanes)
// traces a packet of that many; then answer(i, k) for each ray traced and skip(i) for each other,
// every ray once and in order.
template <int K, class Traced, class Fill, class Launch, class Answer, class Skip>
void in_packets(int64_t n, Traced&& traced, Fill&& fill, Launch&& launch, Answer&& answer, Skip&& skip) {
    int64_t at[K];  // the ray in each lane
    int64_t i = 0;
    while (i < n) {
        const int64_t first = i;
        int lanes = 0;
        for (; i < n && lanes < K; ++i) {
            if (traced(i)) {
                fill(lanes, i);
                at[lanes++] = i;
            }
        }
        if (lanes) launch(lanes);
        for (int64_t j = first, k = 0; j < i; ++j) {  // rays first .. i - 1 answered in order
            if (k < lanes && at[k] == j) {
                answer(j, int(k++));
            } else {
                skip(j);
            }
        }
    }
}

// What a query holds while it traces: denormals flushed, the scene, Embree's context and a
// packet's valid mask.
struct Query {
    const FlushDenormals flush;
    RTCScene scene;
    RTCIntersectContext context;
    alignas(64) int valid[kMaxLanes];
    explicit Query(void* accel) : scene(static_cast<Accel*>(accel)->scene) { rtcInitIntersectContext(&context); }
};

// Closest hits of the batch's n rays: answer(i, packet, k) for ray i traced in lane k of the packet
// (geomID RTC_INVALID_GEOMETRY_ID: a miss), skip(i) for a ray not traced, every ray once and in the
// rays' order. A ray is traced when it is alive (alive null, or alive[i] not 0) and traceable.
template <int K, class Answer, class Skip>
void closest(void* accel, const Rays& rays, int64_t n, const uint8_t* alive, Answer&& answer, Skip&& skip) {
    Query q(accel);
    typename Packet<K>::RayHit packet;
    in_packets<K>(
        n, [&](int64_t i) { return (!alive || alive[i]) && traceable(rays, i); },
        [&](int k, int64_t i) {
            pack(packet.ray, k, rays, i, INFINITY);
            packet.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID, packet.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        },
        [&](int lanes) {
            close_packet<K>(packet.ray, q.valid, lanes);
            Packet<K>::intersect(q.valid, q.scene, &q.context, &packet);
        },
        [&](int64_t i, int k) { answer(i, packet, k); }, skip);
}

}  // namespace

extern "C" {

// A scene of `count` triangles from their corners (count, 3, 3), on a device made with Embree's
// configuration string `config` (null or empty: the defaults); null with `error` set on failure.
void* ir_embree_new(const float* corners, int64_t count, const char* config, char* error, int64_t error_size) try {
    RTCDevice device = rtcNewDevice(config && *config ? config : nullptr);
    if (!device) {
        say(error, error_size, "no device", rtcGetDeviceError(nullptr));
        return nullptr;
    }
    RTCScene scene = rtcNewScene(device);
    RTCGeometry mesh = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(mesh, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), size_t(3 * count)));
    auto* index = static_cast<unsigned*>(rtcSetNewGeometryBuffer(mesh, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), size_t(count)));
    if (!vertices || !index) {
        say(error, error_size, "cannot allocate the triangles", rtcGetDeviceError(device));
        rtcReleaseGeometry(mesh);
        rtcReleaseScene(scene);
        rtcReleaseDevice(device);
        return nullptr;
    }
    for (int64_t i = 0; i < 9 * count; ++i) vertices[i] = corners[i];
    for (int64_t i = 0; i < 3 * count; ++i) index[i] = unsigned(i);
    rtcCommitGeometry(mesh);
    rtcAttachGeometry(scene, mesh);
    rtcReleaseGeometry(mesh);
    rtcCommitScene(scene);
    RTCError code = rtcGetDeviceError(device);
    if (code != RTC_ERROR_NONE) {
        say(error, error_size, "cannot build the scene", code);
        rtcReleaseScene(scene);
        rtcReleaseDevice(device);
        return nullptr;
    }
    const int lanes = rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED) ? 16 : rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED) ? 8 : 4;
    return new Accel{device, scene, lanes};
} catch (...) {  // no C++ exception may cross into ctypes (it would terminate the process)
    std::snprintf(error, size_t(error_size), "Embree: cannot build the scene (out of memory?)");
    return nullptr;
}

// The rays a packet holds (16, 8 or 4).
int64_t ir_embree_lanes(void* accel) { return static_cast<Accel*>(accel)->lanes; }

void ir_embree_free(void* accel) {
    auto* a = static_cast<Accel*>(accel);
    rtcReleaseScene(a->scene);
    rtcReleaseDevice(a->device);
    delete a;
}

// Closest hits of n rays (origins ox, oy, oz and directions dx, dy, dz through their strides, as
// Rays reads them): t (n,) float32, prim (n,) int64, u, v (n,) float32.
void ir_embree_intersect(void* accel, const float* ox, const float* oy, const float* oz, int64_t o_lane, const float* dx, const float* dy, const float* dz, int64_t d_lane, int64_t n, float* t, int64_t* prim, float* u, float* v) {
    auto miss = [&](int64_t i) { t[i] = INFINITY, prim[i] = -1, u[i] = v[i] = 0.0f; };
    with_lanes(accel, [&](auto width) {
        closest<decltype(width)::value>(accel, Rays{{ox, oy, oz}, o_lane, {dx, dy, dz}, d_lane}, n, nullptr, [&](int64_t i, const auto& packet, int k) {
            if (packet.hit.geomID[k] == RTC_INVALID_GEOMETRY_ID) return miss(i);
            t[i] = packet.ray.tfar[k], prim[i] = int64_t(packet.hit.primID[k]), u[i] = packet.hit.u[k], v[i] = packet.hit.v[k];
        }, miss);
    });
}

// Closest hits of n rays (as ir_embree_intersect reads them) compacted to the rays that hit: returns
// their count h, and for j < h, index[j] the j-th ray that hit (in the rays' order) and its hit t[j],
// prim[j], u[j], v[j]; the rays that missed, in order, in gone (unless it is null), the count of
// them in *missed. With alive (n,) bytes, only the rays where it is not 0 are traced, the others
// neither hit nor miss (paths that ended).
int64_t ir_embree_hits(void* accel, const float* ox, const float* oy, const float* oz, int64_t o_lane, const float* dx, const float* dy, const float* dz, int64_t d_lane, int64_t n, const uint8_t* alive, int64_t* index, float* t, int64_t* prim, float* u, float* v, int64_t* gone, int64_t* missed) {
    int64_t h = 0, m = 0;
    auto miss = [&](int64_t i) {
        if (gone && (!alive || alive[i])) gone[m++] = i;
    };
    with_lanes(accel, [&](auto width) {
        closest<decltype(width)::value>(accel, Rays{{ox, oy, oz}, o_lane, {dx, dy, dz}, d_lane}, n, alive, [&](int64_t i, const auto& packet, int k) {
            if (packet.hit.geomID[k] == RTC_INVALID_GEOMETRY_ID) return miss(i);
            index[h] = i, t[h] = packet.ray.tfar[k], prim[h] = int64_t(packet.hit.primID[k]), u[h] = packet.hit.u[k], v[h] = packet.hit.v[k];
            ++h;
        }, miss);
    });
    *missed = m;
    return h;
}

// Shadow rays: hit[i] = 1 when something lies along ray i strictly before tmax[i], else 0.
void ir_embree_occluded(void* accel, const float* ox, const float* oy, const float* oz, int64_t o_lane, const float* dx, const float* dy, const float* dz, int64_t d_lane, const float* tmax, int64_t n, uint8_t* hit) {
    const Rays rays{{ox, oy, oz}, o_lane, {dx, dy, dz}, d_lane};
    with_lanes(accel, [&](auto width) {
        constexpr int K = decltype(width)::value;
        Query q(accel);
        typename Packet<K>::Ray packet;
        in_packets<K>(
            n, [&](int64_t i) { return tmax[i] > 0.0f && traceable(rays, i); },  // false for a NaN tmax too
            [&](int k, int64_t i) { pack(packet, k, rays, i, tmax[i]); },
            [&](int lanes) {
                close_packet<K>(packet, q.valid, lanes);
                Packet<K>::occluded(q.valid, q.scene, &q.context, &packet);
            },
            [&](int64_t i, int k) { hit[i] = packet.tfar[k] < 0.0f; },  // Embree sets tfar = -inf on a hit
            [&](int64_t i) { hit[i] = 0; });
    });
}

}  // extern "C"
