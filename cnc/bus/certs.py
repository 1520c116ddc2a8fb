"""TLS for the network endpoints: a machine's own certificate authority and the certificates it signs.

`waterjet certs` keeps them in one directory per machine (`[zenoh.access] tls_dir`):

    ca.pem, ca.key                the machine's certificate authority (the key stays here, 0600)
    controller.pem, .key          the controller's router (its host names and addresses in the SAN)
    router.pem, .key              a shop router of the machine (same)
    <station>.pem, .key           a station (its name as the common name)

With TLS, Zenoh's `tls/HOST:PORT` endpoints encrypt the traffic, the stations check the router's
certificate against the machine's CA, and the router asks every station for a certificate the
CA signed (mutual TLS): a host without one cannot even open the link, whatever password it
knows. Accounts and roles still come from the user/password login (`cnc.bus.users`). Keys are
ECDSA P-256; certificates last `days` (default 825, the longest browsers accept).
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

DAYS = 825
ROUTERS = ("controller", "router")  # names of the router certificates (server and client use)


class CertError(ValueError):
    """A certificate cannot be made or found; the message names the file and why."""


@dataclass(frozen=True)
class TlsFiles:
    """The files one Zenoh session needs for TLS: the CA to check the other side against, and its own pair."""

    ca: Path
    certificate: Path
    key: Path

    def check(self) -> "TlsFiles":
        for what, path in (("CA certificate", self.ca), ("certificate", self.certificate), ("private key", self.key)):
            if not path.is_file():
                raise CertError(f"{path}: no {what} (make it with `waterjet certs`)")
        return self


def files_for(directory: Path, name: str) -> TlsFiles:
    """The TLS files of `name` (`controller`, `router` or a station) in a machine's TLS directory."""
    return TlsFiles(directory / "ca.pem", directory / f"{name}.pem", directory / f"{name}.key")


def make_ca(directory: Path, machine: str, days: int = DAYS) -> Path:
    """A new certificate authority for `machine` in `directory` (refused when one is there)."""
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    if (directory / "ca.pem").exists():
        raise CertError(f"{directory / 'ca.pem'}: a CA is already there (its certificates would all be invalidated)")
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"waterjet {machine} CA")])
    now = _now()
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True)
            .sign(key, hashes.SHA256()))
    _write(directory, "ca", cert, key)
    return directory / "ca.pem"


def issue(directory: Path, name: str, hosts: list[str] | None = None, days: int = DAYS) -> TlsFiles:
    """A certificate for `name` signed by the directory's CA. A router's (`controller`, `router`)
    names the `hosts` (names or addresses) stations reach it by; a station's is a client's."""
    ca_cert, ca_key = _load_ca(directory)
    if not name or "/" in name or name.startswith(".") or name == "ca":
        raise CertError(f"certificate name {name!r} must be a plain name other than 'ca'")
    router = name in ROUTERS
    if hosts and any(not h.strip() for h in hosts):
        raise CertError(f"a host of the {name} certificate is empty: give names or addresses (--host cnc1.shop)")
    if router and not hosts:
        raise CertError(f"a {name} certificate needs the host names or addresses stations connect to (--host)")
    key = ec.generate_private_key(ec.SECP256R1())
    now = _now()
    builder = (x509.CertificateBuilder()
               .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
               .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now).not_valid_after(now + datetime.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               .add_extension(x509.ExtendedKeyUsage(
                   [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH] if router
                   else [ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False))
    if hosts:
        builder = builder.add_extension(x509.SubjectAlternativeName([_san(h) for h in hosts]), critical=False)
    _write(directory, name, builder.sign(ca_key, hashes.SHA256()), key)
    return files_for(directory, name)


def describe(path: Path) -> str:
    """One line about a certificate: its name, what signed it, its hosts and when it ends."""
    cert = x509.load_pem_x509_certificate(path.read_bytes())
    cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
    try:
        sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        hosts = [str(v) for v in sans.get_values_for_type(x509.DNSName)] + \
                [str(v) for v in sans.get_values_for_type(x509.IPAddress)]
    except x509.ExtensionNotFound:
        hosts = []
    return f"{path.name}: {cn}" + (f" ({', '.join(hosts)})" if hosts else "") + \
        f", valid until {cert.not_valid_after_utc:%Y-%m-%d}"


def _load_ca(directory: Path) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    try:
        cert = x509.load_pem_x509_certificate((directory / "ca.pem").read_bytes())
        key = serialization.load_pem_private_key((directory / "ca.key").read_bytes(), password=None)
    except FileNotFoundError as exc:
        raise CertError(f"{exc.filename}: no CA here: make one first (`waterjet certs ca`)") from None
    except ValueError as exc:
        raise CertError(f"{directory}: the CA cannot be read: {exc}") from None
    return cert, key


def _san(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def _write(directory: Path, name: str, cert: x509.Certificate, key: ec.EllipticCurvePrivateKey) -> None:
    key_path = directory / f"{name}.key"
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                  serialization.NoEncryption()))
    (directory / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc) - datetime.timedelta(minutes=5)  # a little slack for clocks
