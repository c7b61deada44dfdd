"""Fetch a selection set for choosing among trained weights: six CC0 scenes that neither training nor validation uses.

The development scenes' polyhaven-cc0 folder holds 12 of the 18 HDR panoramas (512 x 256, half float, CC0) that the
npm package ``@pmndrs/assets`` 1.7.0 embeds as data URLs; the training recipe reads those 12. This script downloads
the package from the npm registry (checked against its published sha512), decodes the six others (city, forest,
night, studio, sunrise, sunset) and writes them as EXR files to ``OUT/polyhaven-selection/``. Weights can then be
compared on scenes that were never trained on without looking at the 13 validation scenes::

    python -m references.learned_single.fetch_selection_scenes /tmp/selection
    python benchmarks/bench_single.py --data /tmp/selection --methods learned learned:weights=OUT/edge_jump.pt

Nothing is written inside the repository, and an existing file is never overwritten.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import io
import sys
import tarfile
import urllib.request
from pathlib import Path

from torch_modulo.batch.atomic import write_bytes

URL = "https://registry.npmjs.org/@pmndrs/assets/-/assets-1.7.0.tgz"
SHA512 = "zHmKNS+3Jvu9K3zJBQfYQKT9Pn9IQt8s0q/eJC3CXKpWpyg6IBa+ivN9NgDn+fDT2AVjUh2YRZ//GXUueuAdCg=="
#: The package's panoramas that the development scenes do not hold (polyhaven-cc0 has the other 12).
SCENES = ("city", "forest", "night", "studio", "sunrise", "sunset")
PREFIX = "data:application/exr;base64,"


def scenes_from_package(archive: bytes) -> dict[str, bytes]:
    """The EXR bytes of :data:`SCENES` from the package's tarball (each ``package/hdri/<name>.exr.js`` module
    exports one base64 data URL)."""
    out = {}
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        for name in SCENES:
            member = tar.extractfile(f"package/hdri/{name}.exr.js")
            if member is None:
                raise ValueError(f"package/hdri/{name}.exr.js is not a file in {URL}")
            text = member.read().decode("ascii")
            start = text.index(PREFIX) + len(PREFIX)
            data = base64.b64decode(text[start : text.index("'", start)])
            if data[:4] != b"\x76\x2f\x31\x01":  # the OpenEXR magic number
                raise ValueError(f"{name}: the decoded data is not an EXR file")
            out[name] = data
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="folder to write polyhaven-selection/<name>.exr into")
    args = ap.parse_args(argv)
    with urllib.request.urlopen(URL, timeout=120) as response:  # noqa: S310 (a fixed https URL)
        archive = response.read()
    digest = base64.b64encode(hashlib.sha512(archive).digest()).decode("ascii")
    if digest != SHA512:
        print(f"error: {URL} has sha512 {digest}, expected {SHA512}", file=sys.stderr)
        return 1
    folder = args.out / "polyhaven-selection"
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in scenes_from_package(archive).items():
        path = folder / f"{name}.exr"
        if path.exists():
            print(f"kept {path} (exists)")
            continue
        write_bytes(path, data)  # atomic: a partial file never has the final name
        print(f"wrote {path} ({len(data)} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
