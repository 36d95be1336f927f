"""The UERE budget's terms against their published closed forms: the ionospheric obliquity
against IS-GPS-200's Klobuchar factor, the tropospheric mapping of RTCA DO-229 (A.4.2.4), the
airborne multipath term of DO-229 (J.2.4), and the root-sum-square that combines them.

Each would fail if its term were replaced by 1 (no obliquity) or dropped."""

from __future__ import annotations

import numpy as np
import pytest

from virtualgps.receiver import errors

EL_DEG = np.array([5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.0])


def klobuchar_obliquity(el_deg: np.ndarray) -> np.ndarray:
    """IS-GPS-200 20.3.3.5.2.5: F = 1 + 16 (0.53 - E)^3, E in semicircles."""
    return 1.0 + 16.0 * (0.53 - np.asarray(el_deg) / 180.0) ** 3


def test_iono_obliquity_is_klobuchars_within_its_thin_shell_approximation():
    # The thin shell at 350 km and Klobuchar's cubic fit agree within 3.1 % (at 10 deg);
    # both run from ~3 at 5 deg to 1 at the zenith.
    f = errors.iono_obliquity(EL_DEG)
    np.testing.assert_allclose(f, klobuchar_obliquity(EL_DEG), rtol=0.035)
    assert f[0] == pytest.approx(3.04, abs=0.01) and f[-1] == pytest.approx(1.0, abs=1e-12)


def test_tropo_mapping_is_do229s():
    # m(el) = 1.001 / sqrt(0.002001 + sin^2 el): 10.218 at 5 deg, 1.994 at 30 deg, 1 at 90.
    m = errors.tropo_obliquity(EL_DEG)
    np.testing.assert_allclose(m, 1.001 / np.sqrt(0.002001 + np.sin(np.radians(EL_DEG)) ** 2),
                               rtol=1e-12)
    assert m[0] == pytest.approx(10.218, abs=1e-3)
    assert m[4] == pytest.approx(1.994, abs=1e-3)


@pytest.mark.parametrize("term", ["sis", "iono", "tropo", "noise", "multipath"])
def test_uere_sigma_is_each_term_alone_by_its_closed_form(term):
    args = dict(sis_m=0.0, iono_zenith_m=0.0, tropo_zenith_m=0.0, rx_noise_m=0.0,
                multipath_a_m=0.0, multipath_b_m=0.0)
    want = {
        "sis": (("sis_m", 0.8), np.full(EL_DEG.shape, 0.8)),
        "iono": (("iono_zenith_m", 2.0), 2.0 * klobuchar_obliquity(EL_DEG)),
        "tropo": (("tropo_zenith_m", 0.2), 0.2 * 1.001
                  / np.sqrt(0.002001 + np.sin(np.radians(EL_DEG)) ** 2)),
        "noise": (("rx_noise_m", 0.5), np.full(EL_DEG.shape, 0.5)),
        # DO-229 J.2.4: 0.13 + 0.53 exp(-el / 10 deg) metres
        "multipath": (None, 0.13 + 0.53 * np.exp(-EL_DEG / 10.0)),
    }[term]
    if term == "multipath":
        args.update(multipath_a_m=0.13, multipath_b_m=0.53)
    else:
        args[want[0][0]] = want[0][1]
    got = errors.uere_sigma_m(EL_DEG, **args)
    np.testing.assert_allclose(got, want[1], rtol=0.035 if term == "iono" else 1e-12)


def test_uere_sigma_is_the_root_sum_square_of_its_terms():
    budget = dict(sis_m=0.8, iono_zenith_m=2.0, tropo_zenith_m=0.2, rx_noise_m=0.5,
                  multipath_a_m=0.13, multipath_b_m=0.53)
    s = np.sin(np.radians(EL_DEG))
    want = np.sqrt(0.8**2 + (2.0 * errors.iono_obliquity(EL_DEG)) ** 2
                   + (0.2 * 1.001 / np.sqrt(0.002001 + s**2)) ** 2 + 0.5**2
                   + (0.13 + 0.53 * np.exp(-EL_DEG / 10.0)) ** 2)
    np.testing.assert_allclose(errors.uere_sigma_m(EL_DEG, **budget), want, rtol=1e-12)
    # the textbook budget: 6.50 m at 5 deg, 2.22 m at the zenith
    assert errors.uere_sigma_m(5.0, **budget) == pytest.approx(6.50, abs=0.01)
    assert errors.uere_sigma_m(90.0, **budget) == pytest.approx(2.22, abs=0.01)
