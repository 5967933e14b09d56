"""Tests of torchhrc._atomic: the one atomic-write helper behind every file the library writes."""

from __future__ import annotations

import os
import stat

import pytest

from torchhrc._atomic import atomic_write, atomic_write_bytes, atomic_write_text


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_each_form_writes_its_contents_with_the_usual_permissions(tmp_path):
    written = [
        atomic_write_bytes(tmp_path / "a.bin", b"\x00\x01"),
        atomic_write_text(tmp_path / "b.csv", "s,a\r\nü,1\n"),
        atomic_write(tmp_path / "c.txt", lambda tmp: open(tmp, "wb").close()),
    ]
    assert [p.name for p in written] == ["a.bin", "b.csv", "c.txt"]
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01"
    # UTF-8, line ends as given (a CSV's \r\n stays, no newline translation)
    assert (tmp_path / "b.csv").read_bytes() == "s,a\r\nü,1\n".encode()
    assert (tmp_path / "c.txt").read_bytes() == b""
    for path in written:  # not mkstemp's 0o600
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~_umask()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "b.csv", "c.txt"]


def test_a_write_replaces_the_old_file_whole(tmp_path):
    target = tmp_path / "m.json"
    atomic_write_text(target, "old, and longer than the new\n")
    atomic_write_text(str(target), "new\n")  # a str path too
    assert target.read_text() == "new\n"
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_a_failing_write_leaves_the_old_file_intact_and_no_temporary_file(tmp_path, error):
    target = tmp_path / "policy.policyx"
    target.write_bytes(b"the old policy")

    def write(tmp: str) -> None:
        with open(tmp, "wb") as handle:
            handle.write(b"half of the new")
        raise error

    with pytest.raises(type(error)):
        atomic_write(target, write)
    assert target.read_bytes() == b"the old policy"
    assert [p.name for p in tmp_path.iterdir()] == ["policy.policyx"]


def test_the_temporary_file_lies_beside_the_target(tmp_path):
    # os.replace is atomic only within one file system: the temporary file is in the
    # target's own folder, hidden, and named after it
    seen = []
    atomic_write(tmp_path / "t.pomdp", lambda tmp: seen.append(tmp) or open(tmp, "w").close())
    tmp = os.path.basename(seen[0])
    assert os.path.dirname(seen[0]) == str(tmp_path)
    assert tmp.startswith(".t.pomdp.") and tmp.endswith(".tmp")


def test_a_missing_folder_raises_and_writes_nothing(tmp_path):
    with pytest.raises(FileNotFoundError):
        atomic_write_bytes(tmp_path / "absent" / "x", b"1")
    assert list(tmp_path.iterdir()) == []
