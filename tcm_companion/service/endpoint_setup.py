"""Build a :class:`CompanionEndpoint` from configuration and the files that persist it.

The ``[mavlink]`` table of config.toml names the link, the endpoint's settings, and the
files: the signing key (signing is on when it is set; a key readable by others refuses
to start), the signing timestamp and the parameter values (both written back as they
change). The daemon calls :func:`make_endpoint` at start-up and :func:`persist` on
parameter changes and at shutdown.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from ..io.persist import ParamStore, TimestampStore, load_signing_key
from ..mavlink.codec import SigningConfig
from ..mavlink.endpoint import CompanionEndpoint, EndpointConfig


@dataclass(frozen=True)
class MavlinkSettings:
    url: str = "udpout:127.0.0.1:14550"  # e.g. serial:/dev/ttyAMA0:921600
    endpoint: EndpointConfig = field(default_factory=EndpointConfig)
    signing_key_file: str = ""  # empty: no signing
    signing_link_id: int = 0
    # Relative paths are in the state directory ([daemon] state_dir; under systemd
    # /var/lib/tcm-companion through StateDirectory=).
    signing_timestamp_file: str = "signing_timestamp"
    params_file: str = "params.json"


def resolve_state_paths(settings: MavlinkSettings, state_dir: str | Path) -> MavlinkSettings:
    """``settings`` with relative state file paths made absolute under ``state_dir``."""
    base = Path(state_dir)

    def under(name: str) -> str:
        return name if not name or Path(name).is_absolute() else str(base / name)

    return replace(
        settings,
        signing_timestamp_file=under(settings.signing_timestamp_file),
        params_file=under(settings.params_file),
    )


def make_endpoint(settings: MavlinkSettings, now_us: int) -> tuple[CompanionEndpoint, list[str]]:
    """The endpoint with its persisted parameters and signing; returns warnings too.

    Raises :class:`~tcm_companion.io.persist.SigningKeyError` when signing is configured
    but the key cannot be used (missing, malformed, readable by others).
    """
    signing = None
    if settings.signing_key_file:
        key = load_signing_key(settings.signing_key_file)
        stamp = TimestampStore(settings.signing_timestamp_file).load()
        signing = SigningConfig(key, settings.signing_link_id, stamp)
    store = ParamStore(settings.params_file)
    values = store.load()
    endpoint = CompanionEndpoint(settings.endpoint, values, signing, now_us)
    warnings = list(store.warnings)
    if endpoint.params.ignored_initial:
        warnings.append(
            f"{settings.params_file}: ignored out-of-range or unknown "
            f"{', '.join(endpoint.params.ignored_initial)}"
        )
    return endpoint, warnings


def persist(settings: MavlinkSettings, endpoint: CompanionEndpoint) -> None:
    """Write the parameter values and the signing timestamp back."""
    ParamStore(settings.params_file).save(endpoint.params.values)
    if endpoint.codec.signing is not None:
        TimestampStore(settings.signing_timestamp_file).save(endpoint.codec.signing_timestamp)
