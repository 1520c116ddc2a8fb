"""Programs by name (issue 18): a station loads only regular text files of the machine's program
directory, read bounded and without blocking; what is refused is named, never echoed."""

from __future__ import annotations

import os
import threading

import pytest

from cnc.bus.service import CommandRefused
from cnc.programs import ProgramDirectory, read_program

PART = "G21 G90\nG0 X10 Y10\nM3\nG1 X20 F600\nM5\nM2\n"
SECRET = "controller:s3cret-password\n"


@pytest.fixture
def programs(tmp_path) -> ProgramDirectory:
    root = tmp_path / "programs"
    root.mkdir()
    (root / "part.ngc").write_text(PART)
    (tmp_path / "users").write_text(SECRET)
    return ProgramDirectory(root, max_bytes=4096)


def refusal(programs: ProgramDirectory, name: str) -> str:
    with pytest.raises(CommandRefused) as err:
        programs.read(name)
    assert "s3cret" not in str(err.value), "a refusal never echoes the file"
    return str(err.value)


def test_a_plain_name_and_a_path_inside_the_directory_load(programs):
    path, data = programs.read("part.ngc")
    assert data.decode() == PART and path == (programs.root / "part.ngc").resolve()
    assert programs.read(str(programs.root / "part.ngc"))[1].decode() == PART
    assert programs.names() == ["part.ngc"]


def test_a_file_outside_the_directory_is_refused_without_its_contents(programs, tmp_path):
    assert "outside the program directory" in refusal(programs, str(tmp_path / "users"))
    assert "outside the program directory" in refusal(programs, "../users")
    assert "outside the program directory" in refusal(programs, "/etc/passwd")
    assert "no such program" in refusal(programs, "missing.ngc")


def test_a_link_out_of_the_directory_is_refused_and_one_inside_it_followed(programs, tmp_path):
    (programs.root / "leak.ngc").symlink_to(tmp_path / "users")
    assert "outside the program directory" in refusal(programs, "leak.ngc")
    (programs.root / "same.ngc").symlink_to(programs.root / "part.ngc")
    assert programs.read("same.ngc")[1].decode() == PART


def test_devices_pipes_and_directories_are_refused_at_once(programs):
    os.mkfifo(programs.root / "pipe.ngc")
    reader = threading.Thread(target=lambda: refusal(programs, "pipe.ngc"), daemon=True)
    reader.start()
    reader.join(30.0)  # a reader that opened the pipe blocking would wait here for a writer forever
    assert not reader.is_alive(), "a named pipe hung the reader"
    assert "is a named pipe" in refusal(programs, "pipe.ngc")
    (programs.root / "zero.ngc").symlink_to("/dev/zero")
    assert "outside the program directory" in refusal(programs, "zero.ngc")
    with pytest.raises(CommandRefused, match="is a character device"):
        read_program("/dev/zero", 4096)
    (programs.root / "sub").mkdir()
    assert "is a directory" in refusal(programs, "sub")


def test_the_size_is_checked_before_reading(programs):
    (programs.root / "big.ngc").write_text("G0 X1\n" * 1000)
    assert "6000 bytes; this machine accepts at most 4096" in refusal(programs, "big.ngc")


def test_a_binary_or_non_utf8_file_is_refused_by_what_it_is_with_its_line(programs):
    (programs.root / "image.ngc").write_bytes(b"G0 X1\nG0 Y2\n\x89PNG\x00\x01s3cret")
    reason = refusal(programs, "image.ngc")
    assert "line 3: not text: control character 0x00" in reason
    (programs.root / "latin.ngc").write_bytes("G0 X1 (caf\u00e9)\n".encode("latin-1"))
    assert "line 1: not UTF-8 text" in refusal(programs, "latin.ngc")
