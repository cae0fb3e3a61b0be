"""Dev/bench PKI for the zenoh body link: one CA, one robot (server) certificate, client certificates.

    python bench/make_dev_certs.py OUT_DIR      (or: python -m sim_bench.dev_pki OUT_DIR) [--robot-san IP:127.0.0.1 --robot-san DNS:localhost]
                                           [--client capm-commander --client capm-observer]

Writes `ca.pem` (+ `ca.key`), `robot.pem`/`robot.key` (CN `capm-robot`, the SANs given: a TLS
client checks the address it connects to against them) and `<name>.pem`/`<name>.key` per client
(CN = name: the robot side's access-control list matches on it). EC P-256, PEM, PKCS#8 keys, mode
0600. Uses the `openssl` command (present on the robot images and these machines); no Python
dependency. For the bench and tests only: a production CA key lives offline (docs/security.md).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROBOT_CN = "capm-robot"
DEFAULT_CLIENTS = ("capm-commander",)
DEFAULT_ROBOT_SANS = ("IP:127.0.0.1", "DNS:localhost")


@dataclass(frozen=True)
class DevPki:
    dir: Path
    ca: Path
    robot_cert: Path
    robot_key: Path
    clients: dict[str, tuple[Path, Path]]  # CN -> (cert, key)


def _openssl(*args: str, cwd: Path) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise RuntimeError("the openssl command is needed to make dev certificates (apt-get install openssl)")
    out = subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"openssl {' '.join(args[:2])} failed: {out.stderr.strip()[-500:]}")


def _key(path: Path, cwd: Path) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path), cwd=cwd)
    path.chmod(0o600)


def _leaf(out: Path, name: str, cn: str, ca_name: str, sans: tuple[str, ...], usage: str, days: int) -> tuple[Path, Path]:
    key, csr, cert, ext = out / f"{name}.key", out / f"{name}.csr", out / f"{name}.pem", out / f"{name}.ext"
    _key(key, out)
    _openssl("req", "-new", "-key", key.name, "-subj", f"/CN={cn}", "-out", csr.name, cwd=out)
    lines = ["basicConstraints=critical,CA:FALSE", "keyUsage=critical,digitalSignature",
             f"extendedKeyUsage={usage}", "subjectKeyIdentifier=hash", "authorityKeyIdentifier=keyid"]
    if sans:
        lines.append("subjectAltName=" + ",".join(sans))
    ext.write_text("\n".join(lines) + "\n")
    _openssl("x509", "-req", "-in", csr.name, "-CA", f"{ca_name}.pem", "-CAkey", f"{ca_name}.key",
             "-CAcreateserial", "-days", str(days), "-sha256", "-extfile", ext.name, "-out", cert.name, cwd=out)
    csr.unlink()
    ext.unlink()
    return cert, key


def make_dev_pki(
    out_dir: str | os.PathLike,
    clients: tuple[str, ...] | list[str] = DEFAULT_CLIENTS,
    robot_sans: tuple[str, ...] | list[str] = DEFAULT_ROBOT_SANS,
    days: int = 30,
    ca_cn: str = "capm-dev-ca",
    ca_name: str = "ca",
) -> DevPki:
    """Make a CA and leaf certificates in `out_dir` (created). `ca_name` lets a test make a
    second, unrelated CA in the same directory (a stranger's certificates)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ca_key, ca = out / f"{ca_name}.key", out / f"{ca_name}.pem"
    _key(ca_key, out)
    _openssl("req", "-x509", "-new", "-key", ca_key.name, "-subj", f"/CN={ca_cn}", "-days", str(days), "-sha256",
             "-addext", "basicConstraints=critical,CA:TRUE,pathlen:0",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign", "-out", ca.name, cwd=out)
    prefix = "" if ca_name == "ca" else f"{ca_name}-"
    robot_cert, robot_key = _leaf(out, f"{prefix}robot", ROBOT_CN, ca_name, tuple(robot_sans), "serverAuth,clientAuth", days)
    made = {cn: _leaf(out, f"{prefix}{cn}", cn, ca_name, (), "clientAuth", days) for cn in clients}
    return DevPki(out, ca, robot_cert, robot_key, made)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", help="directory for the PEM files (created; keep it out of git)")
    ap.add_argument("--client", action="append", help=f"client certificate common name (repeatable; default {DEFAULT_CLIENTS[0]})")
    ap.add_argument("--robot-san", action="append",
                    help="subjectAltName of the robot certificate, e.g. IP:192.168.50.5 or DNS:spot-payload "
                         f"(repeatable; default {' '.join(DEFAULT_ROBOT_SANS)})")
    ap.add_argument("--days", type=int, default=30, help="validity (days); dev certificates are short-lived")
    a = ap.parse_args(argv)
    pki = make_dev_pki(a.out_dir, tuple(a.client or DEFAULT_CLIENTS), tuple(a.robot_san or DEFAULT_ROBOT_SANS), a.days)
    print(f"CA            {pki.ca}  (key {pki.dir / 'ca.key'}: keep it off the robot)")
    print(f"robot         {pki.robot_cert}  {pki.robot_key}")
    for cn, (c, k) in pki.clients.items():
        print(f"client {cn:<14} {c}  {k}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
