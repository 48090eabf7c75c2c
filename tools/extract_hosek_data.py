"""Write kernels/shading/data/hosek_xyz.npz: the fitted coefficients of Hosek and Wilkie's sky model in CIE XYZ
("An Analytic Model for Full Spectral Sky-Dome Radiance", SIGGRAPH 2012; version 1.4a of the authors' sample
implementation, BSD-3-Clause), which the Sky Texture's Hosek / Wilkie type evaluates (kernels/shading/sky.py).

The numbers are the authors' data set as Cycles ships it (`third_party/sky/source/sky_hosek_data.h` of the
standalone Cycles, or `intern/sky/source/sky_hosek_data.h` of Blender's source): per XYZ channel a distribution
table of 2 ground albedos x 10 turbidities x 6 Bezier control points of the solar elevation x 9 coefficients
(datasetXYZ1..3) and a radiance table of 2 x 10 x 6 (datasetXYZRad1..3). This tool only reads them out of that
header into arrays of those shapes, with the authors' copyright notice beside them:

    python tools/extract_hosek_data.py PATH/TO/sky_hosek_data.h
"""
from __future__ import annotations

import os
import re
import sys

import numpy as np

OUT = os.path.join(os.path.dirname(__file__), "..", "kernels", "shading", "data", "hosek_xyz.npz")
NOTICE = ("Hosek-Wilkie sky model data (CIE XYZ), version 1.4a. Copyright 2012-2013 Lukas Hosek and Alexander "
          "Wilkie, Charles University in Prague. Redistributed under the BSD-3-Clause license of the authors' "
          "sample implementation: redistributions must retain this copyright notice, the list of conditions and "
          "the disclaimer (https://opensource.org/license/bsd-3-clause); neither the names of the copyright "
          "holders nor of the contributors may be used to endorse or promote products derived from it without "
          "specific prior written permission. THE DATA IS PROVIDED AS IS, WITHOUT WARRANTY OF ANY KIND.")


def arrays(text: str) -> dict[str, np.ndarray]:
    """name -> float64 values of each `static const double name[] = {...};` in the header."""
    out = {}
    for name, body in re.findall(r"static const double (\w+)\[\]\s*=\s*\{(.*?)\};", text, re.S):
        body = re.sub(r"//[^\n]*", "", body)
        body = re.sub(r"/\*.*?\*/", "", body, flags=re.S)
        out[name] = np.array([float(v) for v in body.replace("\n", " ").split(",") if v.strip()], np.float64)
    return out


def main(path: str) -> None:
    with open(path, encoding="utf-8") as f:
        found = arrays(f.read())
    xyz = np.stack([found[f"datasetXYZ{c}"] for c in (1, 2, 3)]).reshape(3, 2, 10, 6, 9)
    radiance = np.stack([found[f"datasetXYZRad{c}"] for c in (1, 2, 3)]).reshape(3, 2, 10, 6)
    np.savez_compressed(OUT, xyz=xyz, radiance=radiance, notice=np.array(NOTICE))
    print(f"wrote {os.path.normpath(OUT)}: xyz {xyz.shape}, radiance {radiance.shape}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tools/extract_hosek_data.py PATH/TO/sky_hosek_data.h")
    main(sys.argv[1])
