"""Runs the README's Python lines (its first ```python block under "Python and ComfyUI") as a
user would after installing the wheel, in a scratch folder with the repository's samples."""

import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

repo = Path(__file__).resolve().parents[1]
section = (repo / "README.md").read_text(encoding="utf-8").split("## Python and ComfyUI", 1)[1]
block = re.search(r"```python\n(.*?)```", section, re.S)
if block is None:
    sys.exit("README.md: no ```python block under 'Python and ComfyUI'")
with tempfile.TemporaryDirectory(prefix="matup-readme-") as scratch:
    shutil.copytree(repo / "samples", Path(scratch, "samples"))
    os.chdir(scratch)
    exec(compile(block.group(1), "README.md (Python and ComfyUI)", "exec"), {})
    written = sorted(p.name for p in Path("out/py_wood").iterdir())
print(f"README's Python lines ran; out/py_wood holds {', '.join(written)}")
