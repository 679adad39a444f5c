// Float adds to storage buffers: atomicAdd where the device has float
// atomics (FLOAT_ATOMICS), else compare-and-swap on the float's bits.
#ifndef QTRACE_ATOMICS_GLSL
#define QTRACE_ATOMICS_GLSL

#ifdef FLOAT_ATOMICS
#extension GL_EXT_shader_atomic_float : require
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

// Adds `value` to a float tally: `tally` as a float where the buffer is
// declared float (FLOAT_ATOMICS), `bits` as uint where it is not.
#ifdef FLOAT_ATOMICS
#define ADD_FLOAT(tally, bits, value) atomicAdd(tally, value)
#else
#define ADD_FLOAT(tally, bits, value) CAS_ADD_FLOAT(bits, value)
#endif

#endif
