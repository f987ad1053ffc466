"""``robocal serve --bundle DIR [--config conf/serve/default.yaml] [key=value ...]``: the online compensation
service (protocol: :mod:`robocal.serve.server`). ``robocal serve --model robot-<serial>@production
[--tracking-uri URI]`` serves the registered version the alias points at and swaps in the next one when the alias
moves (:class:`robocal.fleet.registry.AliasWatcher`, through the server's reload).
``robocal serve --make-bundle DIR --calibration FILE [--thermal FILE] [--compliance FILE] --robot NAME [--force]``
writes a bundle instead (a calibration of too few configurations to determine the model only with ``--force``)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from robocal.commands import parse_overrides

DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "conf" / "serve" / "default.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bundle", help="bundle directory to serve (manifest.json + model files)")
    p.add_argument(
        "--model",
        default=None,
        help="serve a registered model by alias, e.g. robot-R0001@production (MLflow); follows the alias when it moves",
    )
    p.add_argument(
        "--tracking-uri",
        default=None,
        help="with --model: MLflow tracking URI (default $MLFLOW_TRACKING_URI, else the repository's mlflow.db)",
    )
    p.add_argument(
        "--model-cache", default=None, help="with --model: download folder (default ~/.cache/robocal/models)"
    )
    p.add_argument("--model-poll-s", type=float, default=10.0, help="with --model: seconds between alias checks")
    p.add_argument(
        "--config", default=None, help=f"service settings YAML (default {DEFAULT_CONFIG.name} of conf/serve)"
    )
    p.add_argument("--host", default=None, help="interface to bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="TCP port (default 7878; 0 picks a free one)")
    p.add_argument("--token-file", default=None, help="file holding the shared token (else $ROBOCAL_SERVE_TOKEN)")
    p.add_argument("--make-bundle", metavar="DIR", default=None, help="write a bundle into DIR and exit")
    p.add_argument("--robot", default=None, help="with --make-bundle: robot name or YAML")
    p.add_argument("--calibration", default=None, help="with --make-bundle: calibration.json")
    p.add_argument("--thermal", default=None, help="with --make-bundle: thermal model JSON")
    p.add_argument("--compliance", default=None, help="with --make-bundle: compliance model JSON")
    p.add_argument(
        "--force",
        action="store_true",
        help="with --make-bundle: write it even from a calibration of too few configurations to determine the model",
    )
    p.add_argument("overrides", nargs="*", help="settings key=value, e.g. safety.max_correction_deg=0.3")


def load_config(path: str | None, overrides: list[str] | None = None) -> dict:
    import yaml

    from robocal.errors import ConfigError

    p = Path(path) if path else DEFAULT_CONFIG
    try:
        cfg = yaml.safe_load(p.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read the serve settings {p}: {exc}") from exc
    if "serve" in cfg and isinstance(cfg["serve"], dict):
        cfg = cfg["serve"]
    for k, v in parse_overrides(overrides).items():
        if isinstance(v, dict) and isinstance(cfg.get(k), dict):
            cfg[k] = {**cfg[k], **v}
        else:
            cfg[k] = v
    return dict(cfg)


def run(args: argparse.Namespace) -> int:
    import asyncio

    from robocal.errors import ConfigError
    from robocal.serve.bundle import load_bundle, write_bundle
    from robocal.serve.server import Server, ServerConfig, read_token
    from robocal.serve.settings import SERVICE_KEYS, ServiceConfig

    if args.make_bundle:
        if not args.calibration or not args.robot:
            raise ConfigError("--make-bundle needs --calibration and --robot")
        out = write_bundle(
            args.make_bundle, args.robot, args.calibration, args.thermal, args.compliance, force=args.force
        )
        b = load_bundle(out)
        print(
            f"wrote bundle {b.bundle_id} to {out} (thermal={b.thermal is not None}, "
            f"compliance={b.compliance is not None})"
        )
        return 0
    watcher = None
    if args.model:
        from robocal.fleet.registry import AliasWatcher, resolve_model

        if args.tracking_uri:  # the flag wins over $MLFLOW_TRACKING_URI (which robocal.tracking puts first)
            os.environ["MLFLOW_TRACKING_URI"] = args.tracking_uri
        version, path = resolve_model(args.model, args.tracking_uri, args.model_cache)
        print(f"robocal serve: {args.model} is version {version}: {path}", flush=True)
        args.bundle = str(path)
    if not args.bundle:
        raise ConfigError("--bundle DIR or --model NAME@ALIAS is required (or --make-bundle DIR)")
    cfg = load_config(args.config, args.overrides)
    if args.host is not None:
        cfg["host"] = args.host
    if args.port is not None:
        cfg["port"] = args.port
    token = read_token(args.token_file, str(cfg.get("token_env") or "ROBOCAL_SERVE_TOKEN"))
    scfg = ServiceConfig.from_mapping({k: cfg[k] for k in SERVICE_KEYS if k in cfg}, token=token)
    server = Server(args.bundle, ServerConfig.from_mapping(cfg), scfg)
    if args.model:  # the alias moved: the new version is swapped in by the server's own reload
        watcher = AliasWatcher(
            args.model, version, server.reload_sync, args.tracking_uri, args.model_cache, args.model_poll_s
        ).start()
    try:
        asyncio.run(server.serve_forever())
    except KeyboardInterrupt:
        pass
    finally:
        if watcher is not None:
            watcher.stop()
    return 0
