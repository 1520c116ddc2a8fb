"""The machine's accounts: who may log in from another host, and in which role.

One file per machine (`[zenoh.access] users_file`, default `<machine>.users` beside the machine
file), written by `waterjet users add|remove` with mode 0600, one account per line:

    name:role:password

Roles, each including the one before:
- `observer` watches: status, position, events, procedures, the histories, the parameters;
- `operator` also commands the machine and holds the command lock, uploads and loads programs;
- `engineer` also changes and saves the control parameters (and, later, selects control programs).

The passwords are kept in clear because Zenoh's user/password authentication needs them so (its
dictionary is a clear-text file); hence the file mode, and a file with looser permissions is
refused. Names `controller`, `local` and `shop` are the controller's own (its processes, a
station on its own host, a shop router) and cannot be accounts.
"""

from __future__ import annotations

import os
import re
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROLES = ("observer", "operator", "engineer")
RESERVED = ("controller", "local", "shop")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}\Z")


class UsersError(ValueError):
    """The users file (or a change to it) is wrong; the message names the file, line and what."""


@dataclass(frozen=True)
class Account:
    name: str
    role: str
    password: str

    def may(self, role: str) -> bool:
        """Whether this account has `role`'s rights (engineers those of operators, and so on)."""
        return ROLES.index(self.role) >= ROLES.index(role)


def role_at_least(role: str, needed: str) -> bool:
    """Whether `role` includes `needed`."""
    return ROLES.index(role) >= ROLES.index(needed)


def check_name(name: str) -> str:
    if not _NAME.match(name or ""):
        raise UsersError(f"user name {name!r} must be 1-32 letters, digits, '-' or '_', starting with a letter or digit")
    if name in RESERVED:
        raise UsersError(f"user name {name!r} is the controller's own ({', '.join(RESERVED)} are reserved)")
    return name


def check_role(role: str) -> str:
    if role not in ROLES:
        raise UsersError(f"role {role!r} is not one of {', '.join(ROLES)}")
    return role


def check_password(password: str) -> str:
    if len(password) < 8:
        raise UsersError("the password must have at least 8 characters")
    if any(c in password for c in "\n\r\0"):
        raise UsersError("the password must not contain line breaks or NUL")
    return password


def read_users(path: Path) -> dict[str, Account]:
    """The accounts of `path`; {} when it does not exist. UsersError names the file and line."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return {}
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise UsersError(f"{path}: readable by others (mode {stat.S_IMODE(st.st_mode):04o}): "
                         f"it holds passwords; chmod 600 {path}")
    accounts: dict[str, Account] = {}
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        name, sep1, rest = line.partition(":")
        role, sep2, password = rest.partition(":")
        if not (sep1 and sep2):
            raise UsersError(f"{path}:{n}: expected name:role:password")
        try:
            account = Account(check_name(name), check_role(role), check_password(password))
        except UsersError as exc:
            raise UsersError(f"{path}:{n}: {exc}") from None
        if name in accounts:
            raise UsersError(f"{path}:{n}: user {name!r} is already on line {_line_of(path, name)}")
        accounts[name] = account
    return accounts


def write_users(path: Path, accounts: dict[str, Account]) -> None:
    """Replace `path` with `accounts`, mode 0600, atomically (a reader sees the old or the new file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write("# waterjet accounts (name:role:password); managed by `waterjet users`, mode 0600\n")
            f.writelines(f"{a.name}:{a.role}:{a.password}\n" for a in accounts.values())
        os.chmod(tmp, 0o600)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _line_of(path: Path, name: str) -> int:
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if line.partition(":")[0] == name:
            return n
    return 0
