// Float adds to storage buffers: 64-bit fixed-point integer adds
// (FIXED_ATOMICS: associative, so the sum does not depend on the order of
// the adds), float atomicAdd (FLOAT_ATOMICS), or compare-and-swap on the
// float's bits.
#ifndef QTRACE_ATOMICS_GLSL
#define QTRACE_ATOMICS_GLSL

#ifdef FLOAT_ATOMICS
#extension GL_EXT_shader_atomic_float : require
#endif
#ifdef FIXED_ATOMICS
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
// Fixed point: 32 fraction bits. A tally holds up to 2^31, far above a
// pass's sum of targets; each add rounds by at most 2^-33.
#define FIXED_ONE 4294967296.0

// `value` in fixed point; NaN and negatives (which targets never are) add 0.
uint64_t to_fixed(float value) {
    float v = value > 0.0 ? min(value, 1.0e9) : 0.0;
    float whole = floor(v);
    return (uint64_t(uint(whole)) << 32) + uint64_t(uint((v - whole) * FIXED_ONE));
}
#endif

// Adds `value` to the float whose bits are the uint `bits` by compare-and-swap.
#define CAS_ADD_FLOAT(bits, value)                                          \
    {                                                                       \
        uint seen = bits;                                                   \
        while (true) {                                                      \
            uint wanted = floatBitsToUint(uintBitsToFloat(seen) + (value)); \
            uint found = atomicCompSwap(bits, seen, wanted);                \
            if (found == seen) {                                            \
                break;                                                      \
            }                                                               \
            seen = found;                                                   \
        }                                                                   \
    }

// Adds `value` to a tally: `tally` as declared for the atomics in use
// (uint64_t, float, or uint holding float bits for compare-and-swap).
#if defined(FIXED_ATOMICS)
#define ADD_TALLY(tally, value) atomicAdd(tally, to_fixed(value))
#elif defined(FLOAT_ATOMICS)
#define ADD_TALLY(tally, value) atomicAdd(tally, value)
#else
#define ADD_TALLY(tally, value) CAS_ADD_FLOAT(tally, value)
#endif

// A tally's element type (the guide update reads tallies as texels:
// guide_build.comp).
#if defined(FIXED_ATOMICS)
#define TALLY uint64_t
#elif defined(FLOAT_ATOMICS)
#define TALLY float
#else
#define TALLY uint
#endif

#endif
