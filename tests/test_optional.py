"""The optional-dependency error names the extra (and, for zarr on Python 3.10, why the extra
did not bring it)."""

import importlib
import sys

import pytest

from torchtof import _optional


def _missing(name):
    raise ImportError(f"No module named {name!r}")


def test_missing_module_names_its_extra(monkeypatch):
    monkeypatch.setattr(importlib, "import_module", _missing)
    with pytest.raises(ImportError, match=r"torchtof acquire needs the optional package 'usb': "
                                          r"pip install 'torchtof\[hardware\]'$"):
        _optional.require("usb", "torchtof acquire")


@pytest.mark.parametrize("version,hint", [((3, 10, 14), True), ((3, 11, 0), False)])
def test_zarr_on_python_3_10_says_the_extra_cannot_install_it(monkeypatch, version, hint):
    monkeypatch.setattr(importlib, "import_module", _missing)
    monkeypatch.setattr(sys, "version_info", version)
    with pytest.raises(ImportError) as err:
        _optional.require("zarr", "torchtof acquire")
    msg = str(err.value)
    assert "pip install 'torchtof[hardware]'" in msg
    assert ("zarr >= 3.1.6 needs Python >= 3.11" in msg) is hint
