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

from ..core.pipeline import PipelineConfig
from ..io.persist import ParamStore, TimestampStore, load_signing_key
from ..mavlink.codec import SigningConfig
from ..mavlink.endpoint import CompanionEndpoint, EndpointConfig
from ..mavlink.params import CONFIG_KEYS, params_from_config


@dataclass(frozen=True)
class MavlinkConfig:
    url: str = "udpout:127.0.0.1:14550"  # e.g. serial:/dev/ttyAMA0:921600
    endpoint: EndpointConfig = field(default_factory=EndpointConfig)
    signing_key_file: str = ""  # empty: no signing
    signing_link_id: int = 0
    # Relative paths are in the state directory ([daemon] state_dir; under systemd
    # /var/lib/tcm-companion through StateDirectory=).
    signing_timestamp_file: str = "signing_timestamp"
    params_file: str = "params.json"


def resolve_state_paths(settings: MavlinkConfig, state_dir: str | Path) -> MavlinkConfig:
    """``settings`` with relative state file paths made absolute under ``state_dir``."""
    base = Path(state_dir)

    def under(name: str) -> str:
        return name if not name or Path(name).is_absolute() else str(base / name)

    return replace(
        settings,
        signing_timestamp_file=under(settings.signing_timestamp_file),
        params_file=under(settings.params_file),
    )


def make_endpoint(
    settings: MavlinkConfig,
    now_us: int,
    pipeline: PipelineConfig | None = None,
) -> tuple[CompanionEndpoint, list[str]]:
    """The endpoint with its persisted parameters and signing; returns warnings too.

    The parameters start from ``pipeline`` (the configuration: :func:`params_from_config`)
    and the persisted values — those set over MAVLink — take precedence; a persisted value
    that differs from the configuration's is named in a warning, so an edit of
    ``config.toml`` that a value set over MAVLink shadows is never silent.

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
    defaults = params_from_config(pipeline) if pipeline is not None else None
    endpoint = CompanionEndpoint(
        settings.endpoint, values, signing, now_us, param_defaults=defaults
    )
    warnings = list(store.warnings)
    params = endpoint.params
    if params.ignored_defaults:
        warnings.append(
            "the configuration's "
            + ", ".join(f"{CONFIG_KEYS[n]} (as {n})" for n in params.ignored_defaults)
            + " is outside the parameter's range: the parameter's default is used"
        )
    if defaults is not None:
        for name in sorted(set(values) & set(defaults)):
            if name in params.ignored_initial or params.values[name] == params.defaults[name]:
                continue
            warnings.append(
                f"{settings.params_file}: {name} = {params.values[name]:g} (set over MAVLink)"
                f" overrides the configuration's {CONFIG_KEYS[name]} = "
                f"{params.defaults[name]:g}; set it over MAVLink again, or delete it from the"
                " file, to follow the configuration"
            )
    if endpoint.params.ignored_initial:
        warnings.append(
            f"{settings.params_file}: ignored out-of-range or unknown "
            f"{', '.join(endpoint.params.ignored_initial)}"
        )
    return endpoint, warnings


def persist(settings: MavlinkConfig, endpoint: CompanionEndpoint) -> None:
    """Write the parameters set over MAVLink (those that differ from the configuration's)
    and the signing timestamp back."""
    ParamStore(settings.params_file).save(endpoint.params.overrides())
    if endpoint.codec.signing is not None:
        TimestampStore(settings.signing_timestamp_file).save(endpoint.codec.signing_timestamp)
