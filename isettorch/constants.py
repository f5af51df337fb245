"""Physical constants, each with its source.

SI values are CODATA 2018 (exact since the 2019 SI redefinition). ``ISETCAM`` holds the
rounded values of ISETCam's ``vcConstants`` for bit-level parity with ISETCam.
"""

from __future__ import annotations

# CODATA 2018 / SI 2019 exact values.
PLANCK_J_S = 6.62607015e-34  # h, CODATA 2018 (exact)
SPEED_OF_LIGHT_M_PER_S = 299_792_458.0  # c, CODATA 2018 (exact)
ELEMENTARY_CHARGE_C = 1.602176634e-19  # q, CODATA 2018 (exact)
BOLTZMANN_J_PER_K = 1.380649e-23  # k_B, CODATA 2018 (exact)

# CIE 015:2018 / SI: maximum luminous efficacy of photopic vision, Km = 683 lm/W.
KM_LM_PER_W = 683.0
# CIE 015:2018: scotopic K'm = 1700 lm/W.
KM_SCOTOPIC_LM_PER_W = 1700.0

# ISETCam vcConstants (ISET/isetcam, utility/vcConstants.m).
ISETCAM = {
    "h": 6.626176e-34,
    "c": 2.99792458e8,
    "q": 1.602177e-19,
}
