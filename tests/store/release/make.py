"""Makes the databases of tests/store/test_release_files.py with the pymb
that runs this script, and what that pymb read out of them (the expected
outputs): ``python tests/store/release/make.py``. The databases are kept as
SQL text (NAME.sql.gz, see release_outputs.dump), not as files. Run once, by the release
whose files the test keeps readable; never by later code (the expected
outputs would then follow whatever that code does)."""

from __future__ import annotations

import gzip
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))  # tests/: release_outputs

from release_outputs import OUTPUTS, dump, outputs  # noqa: E402

from pymb.sim import Simulator  # noqa: E402

CONFIG = """
[output]
path = "{out}"
{extra}

[[bus]]
name = "line"
port = "{port}"
baud = 115200
timeout = 0.3
interval = 1
  [[bus.device]]
  type = "coolpro"
  address = 40
  [[bus.device]]
  type = "hub"
  address = 7
  channels = 6
  humidity_unit = [0.1, 1, 0.1, 1, 0.1, 1]
  [[bus.device]]
  type = "hub"
  address = 9
  name = "big-hub"
  [[bus.device]]
  type = "coolpro"
  address = 41
  name = "absent"
"""

RUNS = {
    "every.db": "",
    "onchange.db": "on_change = true\nheartbeat_s = 2\ndeadband = { temperature_c = 0.2 }",
}


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp, \
            Simulator(["coolpro", "hub:7", "hub:9"], baud=115200, seed=11) as sim:
        for db, extra in RUNS.items():
            out = Path(tmp) / db
            cfg = Path(tmp) / "log.toml"
            cfg.write_text(CONFIG.format(out=out, extra=extra, port=sim.port))
            subprocess.run([sys.executable, "-m", "pymb", "log", "--config", str(cfg),
                            "--seconds", "4"], check=False)  # 3: "absent" gave nothing
            con = sqlite3.connect(out)
            con.execute("VACUUM")
            con.close()
            dump(out, HERE / f"{out.stem}.sql.gz")
        for name, text in outputs(Path(tmp)).items():
            (HERE / f"{name}.gz").write_bytes(gzip.compress(text.encode(), mtime=0))
        assert set(outputs(Path(tmp))) == set(OUTPUTS)


if __name__ == "__main__":
    main()
