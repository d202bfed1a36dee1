#!/usr/bin/env python
"""Make the CURVE keys that let ``launch.py --inspect`` listen on a non-loopback address.

    python tools/make_inspect_keys.py keys/ --clients laptop ci     # on the robot
    python launch.py --inspect tcp://0.0.0.0:5560 --inspect-keys keys/
    python tools/watch_run.py tcp://robot:5560 --client-key keys/clients/laptop.key_secret \\
        --server-key keys/server.key                                 # anywhere (copy the two files)

Layout of DIR: ``server.key`` / ``server.key_secret`` (the launcher's pair), ``clients/<name>.key``
/ ``.key_secret`` (one pair per client; give each client its secret file and server.key), and
``authorized/<name>.key`` (the public keys the launcher accepts; delete one to revoke a client).
Secret files are written readable by the owner only.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

import zmq.auth


def make_keys(folder: Path, clients: list[str]) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    made = {}
    if not (folder / "server.key_secret").is_file():
        zmq.auth.create_certificates(str(folder), "server")
    made["server"] = folder / "server.key_secret"
    for sub in ("clients", "authorized"):
        (folder / sub).mkdir(exist_ok=True)
    for name in clients:
        public, secret = zmq.auth.create_certificates(str(folder / "clients"), name)
        shutil.copy(public, folder / "authorized" / Path(public).name)
        made[name] = Path(secret)
    for secret in folder.rglob("*.key_secret"):
        os.chmod(secret, 0o600)
    return made


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="where the keys go (created)")
    ap.add_argument("--clients", nargs="+", default=["client"], help="names of the clients to make keys for")
    args = ap.parse_args(argv)
    for name, path in make_keys(Path(args.folder), args.clients).items():
        print(f"{name:12s} {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
