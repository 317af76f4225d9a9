"""The how-to's agent (docs/how-to/your-own-agent.md, its first Python block), as a user would copy it: the
docs and the tests stay one."""

from __future__ import annotations

import re
from pathlib import Path

TUTORIAL = Path(__file__).resolve().parents[2] / "docs" / "how-to" / "your-own-agent.md"
USER_MODULE = re.search(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S).group(1)
