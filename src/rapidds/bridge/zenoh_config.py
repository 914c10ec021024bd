"""An authenticated live link: Zenoh's own mutual TLS and access control, from a Zenoh config file.

Without ``--zenoh-config`` the link is plain TCP on localhost, as before. With it, the hub and
every node read a Zenoh configuration file (JSON5, Zenoh's own keys: ``transport/link/tls`` and
``access_control``, as in Zenoh's DEFAULT_CONFIG.json5): the hub listens on ``tls/HOST:PORT``
with its certificate and asks each node for one signed by the cell's CA (``enable_mtls``); its
access control names each node by its certificate's common name and says which keys it may
publish and subscribe to. A peer without such a certificate never gets a session; a node that
publishes on a key it may not is filtered by the hub before any subscriber sees it.

The file is checked before anything is opened, declaratively: Zenoh parses it against its own
schema (unknown keys, wrong types), then the models here check what Zenoh would only find when
a peer connects, or never: the certificate files exist and hold PEM, mutual TLS is on, each role
has its side's certificate and key, access-control rules, subjects and policies refer to each
other, and the file leaves ``mode``, ``listen``, ``connect`` and
``scouting`` to rapidds (the command line names the endpoint; scouting stays off). A bad file
is one line (:class:`LinkConfigError`, exit 2). Relative certificate paths are read relative to
the file, so a folder holding the file and its certificates can move as one.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from rapidds.errors import RapiddsError
from rapidds.settings import error_line

__all__ = ["MAX_CONFIG_BYTES", "LinkConfig", "LinkConfigError", "checked_link_config",
           "load_link_config", "session_config"]

MAX_CONFIG_BYTES = 1 << 20
"""A Zenoh config file larger than this is refused unread (1 MiB: a cell's is a few KiB)."""

Role = Literal["hub", "node"]
_SET_BY_RAPIDDS = ("mode", "listen", "connect", "scouting")
_CERTS = ("root_ca_certificate", "listen_certificate", "connect_certificate")
_KEYS = ("listen_private_key", "connect_private_key")
_NEEDS: dict[str, tuple[str, ...]] = {
    "hub": ("root_ca_certificate", "listen_certificate", "listen_private_key"),
    "node": ("root_ca_certificate", "connect_certificate", "connect_private_key")}
_SECURE_PROTOCOLS = ("tls/", "quic/")
_ZENOH_WHERE = re.compile(r"\s+at /\S+:\d+\.?$")  # the Rust source line Zenoh's errors end with


class LinkConfigError(RapiddsError):
    """A --zenoh-config file that cannot secure the link (unreadable, malformed, inconsistent)."""


class _Tls(BaseModel):
    """``transport/link/tls`` as Zenoh reads it; rapidds checks the files and the mutual part."""

    model_config = ConfigDict(extra="ignore")
    root_ca_certificate: str | None = None
    listen_certificate: str | None = None
    listen_private_key: str | None = None
    connect_certificate: str | None = None
    connect_private_key: str | None = None
    enable_mtls: bool | None = None

    @property
    def files(self) -> dict[str, str]:
        return {k: v for k in (*_CERTS, *_KEYS) if (v := getattr(self, k)) is not None}


class _Rule(BaseModel):
    model_config = ConfigDict(extra="ignore")
    id: str = Field(min_length=1)
    key_exprs: list[str] = Field(min_length=1)
    messages: list[str] = Field(min_length=1)
    permission: Literal["allow", "deny"]


class _Subject(BaseModel):
    model_config = ConfigDict(extra="ignore")
    id: str = Field(min_length=1)
    cert_common_names: list[str] | None = None


class _Policy(BaseModel):
    model_config = ConfigDict(extra="ignore")
    rules: list[str] = Field(min_length=1)
    subjects: list[str] = Field(min_length=1)


class _AccessControl(BaseModel):
    """``access_control``: rules (what), subjects (who), policies (which rules bind whom)."""

    model_config = ConfigDict(extra="ignore")
    enabled: bool = False
    default_permission: Literal["allow", "deny"] = "deny"
    rules: list[_Rule] = Field(default_factory=list)
    subjects: list[_Subject] = Field(default_factory=list)
    policies: list[_Policy] = Field(default_factory=list)

    @field_validator("rules", "subjects", "policies", mode="before")
    @classmethod
    def _none_is_empty(cls, v: Any) -> Any:
        return [] if v is None else v

    @model_validator(mode="after")
    def _consistent(self) -> _AccessControl:
        for what, items in (("rule", self.rules), ("subject", self.subjects)):
            ids = [x.id for x in items]
            dup = sorted({i for i in ids if ids.count(i) > 1})
            if dup:
                raise ValueError(f"{what} id {dup[0]!r} is used twice")
        rules, subjects = {r.id for r in self.rules}, {s.id for s in self.subjects}
        for p in self.policies:
            for name, known, what in ((p.rules, rules, "rule"), (p.subjects, subjects,
                                                                  "subject")):
                unknown = [x for x in name if x not in known]
                if unknown:
                    raise ValueError(f"a policy names {what} {unknown[0]!r}, which is not "
                                     f"declared in {what}s")
        return self

    @property
    def names_certificates(self) -> bool:
        return any(s.cert_common_names for s in self.subjects)


@dataclass(frozen=True)
class LinkConfig:
    """A checked Zenoh config file: its text and, resolved, the TLS files it names."""

    path: Path
    text: str
    role: Role
    tls_files: dict[str, str]
    acl: bool

    @property
    def secure(self) -> bool:
        """Whether the link runs over mutual TLS (then its endpoint must be tls/ or quic/)."""
        return bool(self.tls_files)


def _read(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise LinkConfigError(f"--zenoh-config {path}: {exc.strerror or exc}") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise LinkConfigError(f"--zenoh-config {path}: larger than "
                              f"{MAX_CONFIG_BYTES // 1024} KiB; a cell's config is a few KiB")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise LinkConfigError(f"--zenoh-config {path}: not UTF-8 text") from None


def _pem(path: Path, kind: str, key: str, where: Path) -> None:
    try:
        head = path.read_bytes()[:1 << 16]
    except OSError as exc:
        raise LinkConfigError(f"--zenoh-config {where}: {key} {path}: "
                              f"{exc.strerror or exc}") from None
    if b"-----BEGIN" not in head or kind.encode() not in head:
        raise LinkConfigError(f"--zenoh-config {where}: {key} {path} holds no PEM {kind}")


def _check_tls(tls: _Tls, role: Role, path: Path) -> dict[str, str]:
    """The TLS files, absolute; LinkConfigError unless the role's side is complete and mutual."""
    files = tls.files
    if not files:
        return {}
    missing = [k for k in _NEEDS[role] if k not in files]
    if missing:
        raise LinkConfigError(f"--zenoh-config {path}: a {role} needs transport/link/tls/"
                              f"{missing[0]} (a {role} presents "
                              f"{'listen' if role == 'hub' else 'connect'}_certificate and "
                              "_private_key, signed by root_ca_certificate)")
    if tls.enable_mtls is not True:
        raise LinkConfigError(f"--zenoh-config {path}: transport/link/tls/enable_mtls must be "
                              "true: the hub accepts only nodes whose certificate the cell's CA "
                              "signed")
    out = {}
    for key, value in files.items():
        p = Path(value).expanduser()
        p = p if p.is_absolute() else path.parent / p
        _pem(p, "PRIVATE KEY" if key in _KEYS else "CERTIFICATE", key, path)
        out[key] = str(p.resolve())
    return out


def load_link_config(path: Path, role: Role) -> LinkConfig:
    """Read and check the Zenoh config file of a hub or a node; LinkConfigError when bad."""
    import zenoh

    text = _read(path)
    try:
        conf = zenoh.Config.from_json5(text)
    except Exception as exc:  # Zenoh's own schema: unknown keys, wrong types, bad JSON5
        first = _ZENOH_WHERE.sub("", " ".join(str(exc).split()))[:300] or type(exc).__name__
        raise LinkConfigError(f"--zenoh-config {path}: {first}") from None
    default = zenoh.Config()
    for key in _SET_BY_RAPIDDS:
        if conf.get_json(key) != default.get_json(key):
            raise LinkConfigError(f"--zenoh-config {path} sets '{key}'; rapidds sets "
                                  f"{', '.join(_SET_BY_RAPIDDS)} itself (the endpoint comes "
                                  "from --listen / --connect, scouting stays off)")
    try:
        tls = _Tls.model_validate(json.loads(conf.get_json("transport/link/tls")))
        acl = _AccessControl.model_validate(json.loads(conf.get_json("access_control")))
    except ValidationError as exc:
        raise LinkConfigError(error_line(exc, prefix=f"--zenoh-config {path}: ")) from None
    files = _check_tls(tls, role, path)
    if acl.enabled and acl.names_certificates and not files:
        raise LinkConfigError(f"--zenoh-config {path}: access_control names certificate "
                              "common names, but the file configures no TLS certificates "
                              "(transport/link/tls)")
    return LinkConfig(path, text, role, files, acl.enabled)


def session_config(config: LinkConfig | None, endpoint: str) -> Any:
    """The Zenoh config a session starts from: Zenoh's defaults, or the checked file with its
    TLS paths made absolute. The endpoint must be secure exactly when the file is."""
    import zenoh

    secure = endpoint.startswith(_SECURE_PROTOCOLS)
    if config is None:
        if secure:
            raise LinkConfigError(f"endpoint {endpoint} needs certificates: pass "
                                  "--zenoh-config with transport/link/tls")
        return zenoh.Config()
    if config.secure != secure:
        raise LinkConfigError(
            f"--zenoh-config {config.path} configures TLS, so the endpoint must be "
            f"tls/HOST:PORT, not {endpoint}" if config.secure else
            f"endpoint {endpoint} needs certificates, but --zenoh-config {config.path} "
            "configures none (transport/link/tls)")
    conf = zenoh.Config.from_json5(config.text)
    for key, value in config.tls_files.items():
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    return conf


def checked_link_config(path: Path | None, role: str, endpoint: str) -> LinkConfig | None:
    """The checked ``--zenoh-config`` of a hub or a node (None without one), matched with its
    endpoint, before anything opens or waits; LinkConfigError when either is wrong."""
    if role not in _NEEDS:
        raise ValueError(f"role {role!r}: hub or node")
    config = None if path is None else load_link_config(path, role)  # type: ignore[arg-type]
    session_config(config, endpoint)
    return config
