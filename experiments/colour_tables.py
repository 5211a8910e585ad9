"""Write the colour tables that bubblefit ships, from colour-science's datasets.

``bubblefit/data/cie_1931_2deg.csv``: the CIE 1931 2-degree standard observer, 1 nm,
360-830 nm (CIE 015:2018). ``bubblefit/data/cie_illuminants.csv``: the relative spectral
power of CIE illuminants D65 and A, 5 nm, 300-780 nm (CIE S 014-2). Reading them at run
time costs a millisecond, importing colour-science about a second, so the default colour
path (sRGB under D65, A or E) never imports it; other illuminants and the measured camera
sensitivities still come from colour-science. ``tests/test_spectral.py`` checks that the
shipped tables equal colour-science's.

    python experiments/colour_tables.py
"""

from __future__ import annotations

from pathlib import Path

import colour
import numpy as np

DATA = Path(__file__).resolve().parent.parent / "bubblefit" / "data"


def main() -> None:
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    rows = np.column_stack([cmfs.wavelengths, cmfs.values])
    header = (f"# CIE 1931 2-degree standard observer (CIE 015:2018), from colour-science {colour.__version__}\n"
              "wavelength_nm,x_bar,y_bar,z_bar")
    np.savetxt(DATA / "cie_1931_2deg.csv", rows, delimiter=",", fmt="%.10g", header=header, comments="")
    d65, a = colour.SDS_ILLUMINANTS["D65"], colour.SDS_ILLUMINANTS["A"]
    assert np.array_equal(d65.wavelengths, a.wavelengths)
    rows = np.column_stack([d65.wavelengths, d65.values, a.values])
    header = (f"# CIE illuminants D65 and A, relative spectral power (CIE S 014-2), from colour-science "
              f"{colour.__version__}\nwavelength_nm,D65,A")
    np.savetxt(DATA / "cie_illuminants.csv", rows, delimiter=",", fmt="%.10g", header=header, comments="")
    print(f"wrote {DATA / 'cie_1931_2deg.csv'} and {DATA / 'cie_illuminants.csv'}")


if __name__ == "__main__":
    main()
