"""io_util: atomic outputs."""
import pytest

from leaffit_usd.io_util import atomic_path, atomic_write_bytes


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.usda"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_atomic_output_gets_the_usual_file_mode(tmp_path):
    import os
    import stat

    atomic_write_bytes(tmp_path / "m.bin", b"x")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE((tmp_path / "m.bin").stat().st_mode) == 0o666 & ~mask


def test_atomic_write_replaces(tmp_path):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")
    atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]
