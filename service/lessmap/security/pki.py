"""Keys and certificates of a ``lessmap certs`` site: a test CA and what it issues.

The only module that imports cryptography (``lessmap[security]``); ``certs`` imports it when
a site is made, so ``lessmap certs --help`` and ``--templates`` work without the extra.

1. Private keys are created mode 0600 (never world-readable, not even for a moment).
2. A certificate and its key go to ``<folder>/<stem>.pem`` and ``.key``; the caller names
   the stem (``siteconfig.identity_file``), and a stem with a ``/`` makes its folder.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from typing import TYPE_CHECKING

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from lessmap.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

#: A CA: its private key and its self-signed certificate.
CA = tuple[ec.EllipticCurvePrivateKey, x509.Certificate]


def new_ca(folder: Path, now: datetime.datetime, days: int) -> CA:
    """Make a CA and write it to ``folder`` (``ca.key``, ``ca.pem``)."""
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _certificate("lessmap test CA", key, None, now, days, ca=True)
    _write_key(folder / "ca.key", key)
    (folder / "ca.pem").write_bytes(_pem(cert))
    return key, cert


def load_ca(folder: Path) -> CA:
    """Read the CA a former ``lessmap certs`` wrote to ``folder`` (``--reuse-ca``)."""
    try:
        key = serialization.load_pem_private_key((folder / "ca.key").read_bytes(), None)
        cert = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
    except FileNotFoundError as exc:
        msg = f"--reuse-ca: no CA in {folder} ({exc.filename} is missing)"
        raise ConfigError(msg) from exc
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        msg = f"--reuse-ca: {folder / 'ca.key'} is not an EC key written by lessmap certs"
        raise ConfigError(msg)
    return key, cert


def issue(
    folder: Path,
    name: str,
    ca: CA,
    now: datetime.datetime,
    days: int,
    hosts: Sequence[str] = (),
    stem: str | None = None,
) -> None:
    """Write a new key and a certificate of ``ca`` with CN ``name`` (SAN ``hosts``, if any).

    The files are ``<folder>/<stem>.key`` and ``.pem`` (``stem`` defaults to ``name``).
    """
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _certificate(name, key, ca, now, days, ca=False, hosts=hosts)
    path = folder / (stem or name)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_key(path.with_name(f"{path.name}.key"), key)
    path.with_name(f"{path.name}.pem").write_bytes(_pem(cert))


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    data = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    # Created 0600 (never world-readable, not even for a moment), replaced if it exists.
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as file:
        file.write(data)


def _certificate(
    common_name: str,
    key: ec.EllipticCurvePrivateKey,
    issuer_ca: CA | None,
    now: datetime.datetime,
    days: int,
    *,
    ca: bool,
    hosts: Sequence[str] = (),
) -> x509.Certificate:
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])
    issuer = issuer_ca[1].subject if issuer_ca is not None else subject
    public = key.public_key()
    builder = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(public)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public), critical=False)
        .add_extension(
            x509.KeyUsage(
                digital_signature=not ca,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=ca,
                crl_sign=ca,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
    )
    if not ca:
        builder = builder.add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
    if issuer_ca is not None:
        builder = builder.add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(issuer_ca[1].public_key()),  # type: ignore[arg-type]
            critical=False,
        )
    if hosts:
        names: list[x509.GeneralName] = []
        for host in hosts:
            try:
                names.append(x509.IPAddress(ipaddress.ip_address(host)))
            except ValueError:
                names.append(x509.DNSName(host))
        builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
    signer = issuer_ca[0] if issuer_ca is not None else key
    return builder.sign(signer, hashes.SHA256())
