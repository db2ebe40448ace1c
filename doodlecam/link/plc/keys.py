"""The PLC link's pre-shared keys: one per machine profile, created on first use, kept in the user's config folder.

Authentication is the default (docs/protocol.md 1.9): without a key anyone who can reach the PLC's port could
send it commands. ``doodlecam sim plc`` and ``doodlecam send --udp`` both take the key of the machine profile
from ``<config>/doodlecam/keys/<machine>.key`` (created, readable by the user only, when missing); a real PLC is
paired once by giving it that file's text. A key is never needed on the command line (``--key-file`` reads one
from a file), and keys shorter than ``MIN_KEY`` characters are refused.
"""

from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

from doodlecam.errors import InputError

MIN_KEY = 16  # characters: the protocol document asks for 16 or more random ones


def key_file(machine: str) -> Path:
    """Where the key of machine profile ``machine`` lives (platformdirs: $XDG_CONFIG_HOME is honoured)."""
    from platformdirs import user_config_dir

    safe = re.sub(r"[^A-Za-z0-9._-]", "_", machine).lstrip(".") or "machine"  # a profile name, never a path
    return Path(user_config_dir("doodlecam", appauthor=False)) / "keys" / f"{safe}.key"


def checked(key: str, where: str) -> bytes:
    """A key as the link uses it, or a one-line error when it is too short to be a secret."""
    key = key.strip()
    if len(key) < MIN_KEY:
        raise InputError(f"{where}: the PLC key has {len(key)} characters; use at least {MIN_KEY} random ones "
                         f"(or delete it and let doodlecam create one)")
    return key.encode()


def read_key(path: Path) -> bytes:
    try:
        text = Path(path).read_text("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read the PLC key ({getattr(e, 'strerror', None) or e}); check the path") from None
    return checked(text, str(path))


def machine_key(machine: str) -> tuple[bytes, Path, bool]:
    """(key, its file, whether it was just created) of machine profile ``machine``."""
    path = key_file(machine)
    if path.is_file():
        return read_key(path), path, False
    path.parent.mkdir(parents=True, exist_ok=True)
    text = secrets.token_urlsafe(32)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)  # never replaces a key another process made
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text + "\n")
    return text.encode(), path, True


def profile_key(profile) -> tuple[bytes, str]:
    """The key a machine profile's PLC link uses by default, and where it is from: the profile's
    ``[transport.udp] key``, else the machine's key file (created on first use)."""
    given = profile.plugin_options.get("transport.udp", {}).get("key", "")
    if given:
        return checked(str(given), f"machine '{profile.name}' [transport.udp] key"), \
            f"HMAC key from machine '{profile.name}' [transport.udp] key"
    secret, path, new = machine_key(profile.name)
    return secret, f"HMAC key {'created in' if new else 'from'} {path} (pair a real PLC by giving it this file's text)"
