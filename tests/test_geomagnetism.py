"""The Earth's field from the World Magnetic Model against a published value."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from vdm_aero.geomagnetism import decimal_year, earth_field_ned_ut


def test_wmm2025_matches_the_published_example() -> None:
    # MathWorks' wrldmagm documentation example: WMM2025 at 42.283° N, 71.35° W, 1000 m on 2028-07-04:
    # X = 20139 nT, Y = −4905 nT, Z = 46532 nT (the numbers the nav scenarios' magnetic field was written from)
    year = decimal_year(dt.datetime(2028, 7, 4, tzinfo=dt.UTC).timestamp())
    field, source = earth_field_ned_ut(42.283, -71.35, 1000.0, year)
    assert np.allclose(field, [20.139, -4.905, 46.532], atol=0.002)
    assert source.startswith("WMM2025") and "extrapolated" not in source


def test_epochs_and_extrapolation_are_named() -> None:
    assert earth_field_ned_ut(47.4, 8.5, 500.0, 2017.3)[1].startswith("WMM2015")
    f, source = earth_field_ned_ut(47.4, 8.5, 500.0, 2032.0)
    assert "extrapolated" in source and 40.0 < float(np.linalg.norm(f)) < 60.0
    assert decimal_year(dt.datetime(2021, 1, 1, tzinfo=dt.UTC).timestamp()) == pytest.approx(2021.0)
