#!/usr/bin/env python3
"""Reference values for tests/ephemeris_spice.rs, computed with CSPICE (through
spiceypy) from the kernels of tools/fetch_kernels.sh: independent of anise and
of optistim's code.

Writes tests/data/spice_reference.csv: for each epoch, the TDB seconds past
J2000 (str2et), the geometric Moon position wrt the Earth and Sun position wrt
the Moon in J2000 (km), and the rotations MOON_PA -> J2000 and MOON_ME -> J2000
(pxform, row-major, 9 numbers each).

Usage: pip install spiceypy; tools/fetch_kernels.sh; python3 tools/spice_reference.py
"""
import os
import sys

import spiceypy as sp

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
KERNELS = os.path.join(ROOT, "data", "kernels")
OUT = os.path.join(ROOT, "tests", "data", "spice_reference.csv")

# UTC epochs across the kernels' span, both AMIE images, a leap-second day,
# and two epochs given in TDB (the " TDB" suffix the scene files accept).
EPOCHS = [
    "1950-01-01T00:00:00 UTC",
    "1999-12-31T23:59:59 UTC",
    "2004-08-19T23:42:43.134 UTC",
    "2004-10-28T02:05:10.920 UTC",
    "2008-12-31T23:59:59 UTC",
    "2009-01-01T00:00:00 UTC",
    "2015-07-01T12:00:00 UTC",
    "2024-04-08T18:17:00 UTC",
    "2049-06-30T06:30:00 UTC",
    "2000-01-01T12:00:00 TDB",
    "2030-02-14T03:04:05.5 TDB",
]


def main():
    for k in ["naif0011.tls", "pck00010.tpc", "moon_080317.tf",
              "moon_pa_de421_1900-2050.bpc", "de421.bsp"]:
        sp.furnsh(os.path.join(KERNELS, k))
    with open(OUT, "w") as f:
        f.write(f"# tools/spice_reference.py with spiceypy {sp.__version__}, "
                f"{sp.tkvrsn('TOOLKIT')}; kernels de421.bsp, "
                "moon_pa_de421_1900-2050.bpc, moon_080317.tf, naif0011.tls\n")
        cols = ["epoch", "et_s"]
        cols += [f"moon_wrt_earth_{a}_km" for a in "xyz"]
        cols += [f"sun_wrt_moon_{a}_km" for a in "xyz"]
        cols += [f"pa_to_j2000_{i}{j}" for i in range(3) for j in range(3)]
        cols += [f"me_to_j2000_{i}{j}" for i in range(3) for j in range(3)]
        f.write(",".join(cols) + "\n")
        for text in EPOCHS:
            et = sp.str2et(text.replace("T", " ", 1))  # SPICE: no ISO "T" with a scale
            moon, _ = sp.spkpos("MOON", et, "J2000", "NONE", "EARTH")
            sun, _ = sp.spkpos("SUN", et, "J2000", "NONE", "MOON")
            pa = sp.pxform("MOON_PA", "J2000", et)
            me = sp.pxform("MOON_ME", "J2000", et)
            row = [text, repr(et)]
            row += [repr(float(v)) for v in moon]
            row += [repr(float(v)) for v in sun]
            row += [repr(float(v)) for r in pa for v in r]
            row += [repr(float(v)) for r in me for v in r]
            f.write(",".join(row) + "\n")
    print(f"wrote {OUT}", file=sys.stderr)


if __name__ == "__main__":
    main()
