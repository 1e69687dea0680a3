"""The run's credential: a command only the holders of the run's key can make (pure).

The graph's node names can be spoofed (sources.py) and DDS Security is not in the
Fast DDS wheel, so every command that can move the machine carries a tag that only a
process holding the run's key can compute:

    pkm-cred/1 <sender> <seq> <size> <mac>

``mac`` is HMAC-SHA256 (RFC 2104, Python's ``hmac``) keyed with the run's 32-byte key,
over the topic (relative: ``goal``, ``controller/settings``) and the message's first
``size`` serialized (CDR) bytes, the whole message as its sender serialized it, in
which the 64 hex digits of the mac itself are zeros. So the tag binds the sender's
name, the sequence number and every field of the message. (``size``, 10 digits: a
reader gets the bytes padded to a multiple of 4, which its decoders ignore.)
``seq`` only grows per sender (a signer starts it at the wall clock in ns): a verifier
takes from each sender, on each topic, only a seq above the last it took there (DDS
keeps one writer's order, not the order across topics) and above its own creation
time, so a message recorded off the wire and sent again is refused, and so is one
recorded in an earlier run with the same key (``--credential``) or before a node was
configured again. A sender that publishes one topic from two threads signs and
publishes under one lock (the panel does). The tag is ASCII, parsed by one strict
pattern (``TAG``); node names are ROS names (letters, digits, ``_``, ``/``).

The tag is the message's first string:
- a stamped command (``goal``, ``trajectory``, ``load``) carries it as
  ``header.frame_id`` (a command's frame is the world frame);
- a std_msgs/String command (``program``, ``controller/settings``,
  ``controller/feed_override``, ``run/start``) carries it as its first line, before the
  body (a G-code program, a JSON object, a number, ``start``).
A node without a key (started by hand, outside a run) takes the body and ignores a tag.

The key is made by pkm-run for each run (``credential.key`` in the run directory,
mode 0600, or ``pkm-run --credential FILE``), given to the nodes it starts (the
``credential_file`` parameter) and to the panel (``pkm-panel --start`` makes it;
``--credential`` to join a run). A user's script that is given the file signs with
``Signer``.

What this protects against: a process that cannot read the key file (another user, a
container or host that shares the DDS domain, a web page, a node of an earlier run, a
stray script) cannot command the run, whatever node name it takes, nor replay a
command it recorded, nor alter one in flight. What it does not: a process of the same
user that reads the key file (or a root process); reading the commands (nothing is
encrypted); a flood that keeps the nodes busy (refused messages still cost their
check); the streams of the loop itself (``drives/*``, the metrology), whose sources
are checked by name (sources.py); a clock set back by more than a sender's rate
(its new seq is below the old: refused until the clock passes it).
"""

from __future__ import annotations

import hmac
import os
import re
import secrets
import stat
import threading
import time
from dataclasses import dataclass
from hashlib import sha256
from pathlib import Path

from pkm_common.cdr import encode_string, first_string_span
from pkm_kinematics.errors import FieldError

__all__ = ["COMMAND_TOPICS", "KEY_FILE", "CredentialRefused", "RunKey", "SCHEME", "Signer", "Verifier", "split_text"]

SCHEME = "pkm-cred/1"
KEY_BYTES = 32
MAC_HEX = 64
ZERO_MAC = "0" * MAC_HEX
SIZE_DIGITS = 10
KEY_FILE = "credential.key"            # in the run directory
SENDER = re.compile(r"/[A-Za-z0-9_/~]{1,255}")
# the whole tag, at the start of the first string; the groups: sender, seq, size, mac
TAG = re.compile(rb"pkm-cred/1 (/[A-Za-z0-9_/~]{1,255}) ([0-9]{1,20}) ([0-9]{10}) ([0-9a-f]{64})(?=\n|$)")
# the commands that carry it, and whether the message is stamped (the tag in header.frame_id)
COMMAND_TOPICS = {"goal": True, "trajectory": True, "load": True, "program": False, "controller/settings": False,
                  "controller/feed_override": False, "run/start": False}


@dataclass(frozen=True)
class CredentialRefused:
    """Why a command was not taken, and the sender its tag names ("" when it names none
    or the tag cannot be trusted)."""

    reason: str
    sender: str = ""


class RunKey:
    """A run's secret key (``KEY_BYTES``), kept in a file only its owner reads."""

    def __init__(self, key: bytes):
        if len(key) != KEY_BYTES:
            raise ValueError(f"credential key: must be {KEY_BYTES} bytes, got {len(key)}")
        self._key = key

    @classmethod
    def create(cls, path) -> "RunKey":
        """A new random key written to ``path`` (mode 0600; an existing file is replaced)."""
        path = Path(path)
        key = cls(secrets.token_bytes(KEY_BYTES))
        tmp = path.with_name(path.name + ".tmp")
        tmp.unlink(missing_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w", encoding="ascii") as fh:
            fh.write(key._key.hex() + "\n")
        os.replace(tmp, path)
        return key

    @classmethod
    def read(cls, path) -> "RunKey":
        """The key in ``path``; a file others may read is refused (its key is no secret)."""
        path = Path(path)
        try:
            mode = path.stat().st_mode
            text = path.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError) as exc:
            raise FieldError("credential_file", f"cannot read {path}: {exc}") from None
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise FieldError("credential_file", f"{path} may be read by others (mode {stat.S_IMODE(mode):o}); "
                                                "it must be 600")
        try:
            return cls(bytes.fromhex(text))
        except ValueError:
            raise FieldError("credential_file", f"{path} does not hold {KEY_BYTES} bytes in hex") from None

    def mac(self, topic: str, buf, mac_at: int | None = None, size: int | None = None) -> bytes:
        """HMAC-SHA256 over the topic, a NUL and ``buf[:size]``, the 64 bytes at
        ``mac_at`` taken as zeros (no copy of a long trajectory), in hex (ASCII)."""
        view = memoryview(buf)[:len(buf) if size is None else size]
        h = hmac.new(self._key, topic.encode("utf-8") + b"\x00", sha256)
        if mac_at is None:
            h.update(view)
        else:
            h.update(view[:mac_at])
            h.update(ZERO_MAC.encode("ascii"))
            h.update(view[mac_at + MAC_HEX:])
        return h.hexdigest().encode("ascii")


def _find_tag(buf, stamped: bool, topic: str):
    """(match, offset of the first string) of the tag at the start of the message's
    first string, or (None, offset)."""
    start, end = first_string_span(buf, stamped, topic)
    return TAG.match(bytes(memoryview(buf)[start:min(end, start + 400)])), start


def split_text(text: str) -> tuple[str, str]:
    """(tag, body) of a String command: its first line when that is a tag, else ("", text)."""
    if text.startswith(SCHEME + " "):
        tag, _, body = text.partition("\n")
        return tag, body
    return "", text


class Signer:
    """Makes the tags of one sender (its full node name) with the run's key."""

    def __init__(self, key: RunKey, sender: str, clock=time.time_ns):
        if not SENDER.fullmatch(sender):
            raise ValueError(f"credential sender: a full ROS node name (/ns/name), got {sender!r}")
        self.key, self.sender, self.clock = key, sender, clock
        self.seq = 0
        self.lock = threading.Lock()

    def placeholder(self) -> str:
        """The next tag with a zero mac: set it as the message's first string, serialize,
        then ``seal``."""
        with self.lock:
            self.seq = seq = max(self.seq + 1, self.clock())
        return f"{SCHEME} {self.sender} {seq} {'0' * SIZE_DIGITS} {ZERO_MAC}"

    def seal(self, topic: str, buf, stamped: bool) -> bytes:
        """The serialized message with its placeholder's mac filled in."""
        found, start = _find_tag(buf, stamped, topic)
        if found is None or found.group(4) != ZERO_MAC.encode("ascii"):
            raise ValueError(f"{topic}: the message's first string is not a placeholder tag")
        out = bytearray(buf)
        out[start + found.start(3):start + found.end(3)] = f"{len(out):0{SIZE_DIGITS}d}".encode("ascii")
        mac_at = start + found.start(4)
        out[mac_at:mac_at + MAC_HEX] = self.key.mac(topic, out)
        return bytes(out)

    def text(self, topic: str, body: str) -> bytes:
        """A serialized std_msgs/String command: the tag's line, then ``body``."""
        return self.seal(topic, encode_string(f"{self.placeholder()}\n{body}"), stamped=False)


class Verifier:
    """Checks the tags of one run's commands (``key`` None: none is required)."""

    def __init__(self, key: RunKey | None, clock=time.time_ns):
        self.key = key
        self.created_ns = clock()             # a seq (a signer's wall clock) from before: recorded earlier
        self.last_seq: dict[tuple, int] = {}    # (sender, topic) -> last seq taken (only key holders)

    @property
    def required(self) -> bool:
        return self.key is not None

    def check(self, topic: str, buf, stamped: bool) -> tuple[str, CredentialRefused | None]:
        """(sender, None) for a command of a key holder, taken once; else ("", why). A
        malformed message raises ValueError (as its decoder would). Without a key
        every command is taken (its tag, if any, unchecked)."""
        if self.key is None:
            return "", None
        found, start = _find_tag(buf, stamped, topic)
        if found is None:
            return "", CredentialRefused(f"{topic}: no credential ({SCHEME} tag) in the message")
        sender, seq, size, mac = (found.group(1).decode("ascii"), int(found.group(2)), int(found.group(3)),
                                  found.group(4))
        mac_at = start + found.start(4)
        if not mac_at + MAC_HEX <= size <= len(buf):
            return "", CredentialRefused(f"{topic}: credential of {sender} for {size} bytes, the message has "
                                         f"{len(buf)}")
        if not hmac.compare_digest(mac, self.key.mac(topic, buf, mac_at, size)):
            return "", CredentialRefused(f"{topic}: credential not valid for this run (says {sender}): "
                                         "another key, or the message was altered")
        last = max(self.last_seq.get((sender, topic), 0), self.created_ns)
        if seq <= last:
            return sender, CredentialRefused(f"{topic}: a replayed command of {sender} (seq {seq}, not after "
                                             f"{last})", sender)
        self.last_seq[sender, topic] = seq
        return sender, None

    def refusal(self, topic: str, buf, stamped: bool, allowed=frozenset()) -> CredentialRefused | None:
        """Why a command is not taken, naming its sender (or ``(no credential)``,
        ``(unreadable)``): no valid credential, or a key holder not among ``allowed``
        (full node names; empty: any). None: taken."""
        try:
            sender, refused = self.check(topic, buf, stamped)
        except (ValueError, TypeError) as exc:
            return CredentialRefused(str(exc), "(unreadable)")
        if refused is not None:
            return CredentialRefused(refused.reason, refused.sender or "(no credential)")
        if self.required and allowed and sender not in allowed:
            return CredentialRefused(f"{topic}: {sender} holds the run's credential but may not send it (only "
                                     f"{', '.join(sorted(allowed))})", sender)
        return None

    @classmethod
    def from_file(cls, path: str) -> "Verifier":
        """The verifier of a node's ``credential_file`` parameter ("": none required)."""
        return cls(RunKey.read(path) if path else None)
