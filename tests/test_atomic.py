import os
import stat

import pytest

from terrain import InputError
from terrain.atomic import atomic_path, ensure_writable_dir


def test_atomic_path_success_and_failure(tmp_path):
    target = tmp_path / "a.json"
    with atomic_path(target) as tmp:
        tmp.write_text("{}")
        assert not target.exists()  # nothing at the final name until success
    assert target.read_text() == "{}"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "b.json") as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]  # no partial, no temp


def test_unwritable_output_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError, match="--out"):
        ensure_writable_dir(blocker / "sub")
