"""tools/trim_wheel.py (used by tools/device_site.sh): a wheel copied without some folders
installs with pip, offline, with exactly the files left, and its RECORD names only those."""

from __future__ import annotations

import importlib.util
import pathlib
import subprocess
import sys
import zipfile

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _trim_wheel():
    spec = importlib.util.spec_from_file_location("trim_wheel", ROOT / "tools" / "trim_wheel.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.trim_wheel


def _wheel(path: pathlib.Path) -> pathlib.Path:
    """A small pure-Python wheel with a package, an asset folder and a nested one to cut."""
    files = {"pkg/__init__.py": "VALUE = 1\n", "pkg/mjcf/__init__.py": "", "pkg/suite/__init__.py": "",
             "pkg/suite/assets/big.xml": "<x/>" * 1000, "pkg/suiteX.py": "KEPT = True\n"}
    info = "pkg-1.0.dist-info"
    meta = {f"{info}/METADATA": "Metadata-Version: 2.1\nName: pkg\nVersion: 1.0\n",
            f"{info}/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"}
    record = "".join(f"{name},,\n" for name in [*files, *meta]) + f"{info}/RECORD,,\n"
    out = path / "pkg-1.0-py3-none-any.whl"
    with zipfile.ZipFile(out, "w") as z:
        for name, text in {**files, **meta, f"{info}/RECORD": record}.items():
            z.writestr(name, text)
    return out


def test_a_trimmed_wheel_installs_without_the_cut_folders(tmp_path):
    src = _wheel(tmp_path)
    (tmp_path / "out").mkdir()
    trimmed = _trim_wheel()(src, tmp_path / "out", ["pkg/suite"])
    with zipfile.ZipFile(trimmed) as z:
        names = set(z.namelist())
        record = z.read("pkg-1.0.dist-info/RECORD").decode()
    assert not any(n.startswith("pkg/suite/") for n in names) and "pkg/suiteX.py" in names
    assert {line.split(",")[0] for line in record.splitlines()} == names  # RECORD lists what is there
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--target", str(target),
                    str(trimmed)], check=True)
    assert (target / "pkg" / "mjcf" / "__init__.py").is_file() and (target / "pkg" / "suiteX.py").is_file()
    assert not (target / "pkg" / "suite").exists()
