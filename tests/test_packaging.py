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


def test_docs_speak_of_the_project_only():
    """README and docs name figures, commands and machines, not how the work was organised."""
    banned = re.compile(r"\bissue \d|\bissues? #?\d|\bsessions?\b|reference index|"
                        r"no GPU was available|at commit|\bcommit `?[0-9a-f]{7,40}\b", re.I)
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            assert not banned.search(line), f"{path.name}:{number}: {line}"


def test_readme_links_the_bundle_format_and_outputs_in_one_place():
    readme = (ROOT / "README.md").read_text()
    assert "docs/conventions.md#outputs" in readme
    conventions = (ROOT / "docs" / "conventions.md").read_text()
    errors = (ROOT / "docs" / "errors.md").read_text()
    assert "## Scene bundle" in conventions and "## Outputs" in conventions
    assert '"camera_to_world"' in conventions and '"camera_to_world"' not in errors
    assert "conventions.md#scene-bundle" in errors
