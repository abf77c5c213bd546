"""Certificates for tests: a fleet's, made by ``armtwin certs`` from a fleet description (the CA,
the router's server certificate, a client certificate per name); an HTTPS server's (the
dashboard's, outside the fleet's roles), made with the openssl CLI; and the TLS settings of a
Zenoh client that presents one."""

from __future__ import annotations

import subprocess
from pathlib import Path


def make_fleet_certs(armtwin_bin: Path, fleet: Path, folder: Path, *flags: str) -> None:
    """``armtwin certs FLEET FOLDER FLAGS…``, which must succeed."""
    result = subprocess.run([str(armtwin_bin), "certs", str(fleet), str(folder), *flags],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def make_ca(folder: Path, name: str) -> None:
    openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.pem", "-days", "2", "-subj", f"/CN={name}",
        "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=keyCertSign,cRLSign",
        cwd=folder,
    )


def make_https_cert(folder: Path, name: str, ca: str = "ca") -> None:
    """An HTTPS server's certificate for ``localhost`` and ``127.0.0.1``, signed by ``ca``."""
    extensions = folder / f"{name}.ext"
    extensions.write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature\nextendedKeyUsage=serverAuth\n"
    )
    openssl(
        "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}", cwd=folder,
    )
    openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
        "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", extensions.name,
        cwd=folder,
    )


def tls_of(certs: Path, name: str | None) -> dict:
    tls = {"root_ca_certificate": str(certs / "ca.pem"), "enable_mtls": True,
           "verify_name_on_connect": True}
    if name is not None:
        tls["connect_private_key"] = str(certs / f"{name}.key")
        tls["connect_certificate"] = str(certs / f"{name}.pem")
    return tls
