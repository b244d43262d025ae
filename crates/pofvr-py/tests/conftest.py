"""Shared paths and volumes for the pofvr Python tests."""

import os
import pathlib

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]
TFS = REPO / "tfs"


def data_dir():
    """../shared/data (or $POFVR_DATA), or None when absent."""
    d = pathlib.Path(os.environ.get("POFVR_DATA", REPO.parent / "shared" / "data"))
    return d if (d / "CATALOG.md").is_file() else None


@pytest.fixture(scope="session")
def cli():
    """The `pofvr` binary: $POFVR_BIN or target/release/pofvr (`cargo build --release -p pofvr-cli`)."""
    p = pathlib.Path(os.environ.get("POFVR_BIN", REPO / "target" / "release" / "pofvr"))
    if not p.is_file():
        pytest.fail(f"{p} not found: build it with `cargo build --release -p pofvr-cli` or set POFVR_BIN")
    return p


def blobs(shape, dtype, scale):
    """A smooth volume of overlapping Gaussian blobs (z, y, x), values 0..scale, in `dtype`."""
    z, y, x = np.meshgrid(*[np.linspace(-1, 1, n) for n in shape], indexing="ij")
    v = (
        np.exp(-((x - 0.2) ** 2 + y**2 + (z + 0.1) ** 2) / 0.25)
        + 0.8 * np.exp(-((x + 0.4) ** 2 + (y - 0.3) ** 2 + z**2) / 0.08)
        + 0.6 * np.exp(-(x**2 + (y + 0.4) ** 2 + (z - 0.4) ** 2) / 0.04)
    )
    v = v / v.max() * scale
    return np.ascontiguousarray(v.astype(dtype))


def family(top):
    """A two-basis family over values 0..top, as a dict (the shape of a TF JSON file)."""
    return {
        "bases": [
            {"name": "soft", "opacity": [[0.15 * top, 0.0], [0.35 * top, 0.08], [0.6 * top, 0.0]]},
            {"name": "core", "opacity": [[0.55 * top, 0.0], [0.8 * top, 0.6], [top, 0.9]]},
        ],
        "weights": [1.0, 1.0],
        "color": [[0, 0.2, 0.3, 0.9], [0.4 * top, 0.9, 0.6, 0.3], [top, 1, 1, 0.9]],
    }
