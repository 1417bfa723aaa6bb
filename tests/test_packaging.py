"""The licence file and the package metadata agree."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_license_is_the_full_apache_2_text_named_in_pyproject():
    text = (ROOT / "LICENSE").read_text()
    assert text.lstrip().startswith("Apache License\n")
    assert "Version 2.0, January 2004" in text and "END OF TERMS AND CONDITIONS" in text
    # The canonical https://www.apache.org/licenses/LICENSE-2.0.txt, byte for byte.
    assert hashlib.md5((ROOT / "LICENSE").read_bytes()).hexdigest() == \
        "3b83ef96387f14655fc854ddc3c6bd57"
    pyproject = (ROOT / "pyproject.toml").read_text()     # (tomllib needs Python 3.11)
    assert re.search(r'^license = (\{ text = )?"Apache-2.0"', pyproject, re.M)
