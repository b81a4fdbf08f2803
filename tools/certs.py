"""``placecell-certs``: a site's certificate authority and the identities it vouches for
(docs/security.md).

Who may speak for a robot is decided by zenoh's access control on every node, by the
common name (CN) of the certificate each node shows over mutual TLS: the robot's
certificate carries the robot's name, an operator's and a viewer's their own names.
This tool makes the site's CA once and one certificate per identity:

    placecell-certs ca /etc/placecell/tls                 # ca.pem, ca.key (keep ca.key off robots)
    placecell-certs issue /etc/placecell/tls sim1         # sim1.pem, sim1.key: the robot
    placecell-certs issue /etc/placecell/tls alice        # an operator (listed in the ACLs)

Keys are ECDSA P-256, certificates valid for ``--days`` (default 825); each names
``localhost`` and 127.0.0.1 beside its CN so loopback setups verify as well.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
import re
import sys
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

# An identity is a name a site writes into its ACL files: letters, digits, '-', '_', '.'.
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class CertError(Exception):
    """A CA or identity that cannot be made (bad name, missing CA, existing files)."""


def _write_private(path: Path, data: bytes) -> None:
    """A key file readable by its owner only, never overwriting one that exists."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def make_ca(directory: Path, name: str = "placecell site CA", days: int = 3650) -> Path:
    """The site's CA: ``ca.pem`` (given to every node) and ``ca.key`` (signs identities)."""
    directory.mkdir(parents=True, exist_ok=True)
    cert_path, key_path = directory / "ca.pem", directory / "ca.key"
    if cert_path.exists() or key_path.exists():
        raise CertError(f"{directory} already holds a CA (ca.pem/ca.key); not replaced")
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, key_cert_sign=True,
                                         crl_sign=True, encipher_only=False,
                                         decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    _write_private(key_path, _key_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path


def issue(directory: Path, name: str, days: int = 825) -> tuple[Path, Path]:
    """``<name>.pem`` and ``<name>.key``: an identity with CN = ``name``, signed by the
    CA in ``directory``, usable as TLS server and client (zenoh peers are both)."""
    if not _NAME.match(name):
        raise CertError(f"identity {name!r}: use letters, digits, '-', '_' or '.' "
                        "(at most 64, starting with a letter or digit)")
    if name == "ca":
        raise CertError("identity 'ca' is the CA's own file name; choose another")
    try:
        ca_cert = x509.load_pem_x509_certificate((directory / "ca.pem").read_bytes())
        ca_key = serialization.load_pem_private_key((directory / "ca.key").read_bytes(), None)
    except FileNotFoundError as e:
        raise CertError(f"no CA in {directory} ({e.filename}): run "
                        f"'placecell-certs ca {directory}' first") from e
    if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
        raise CertError(f"{directory / 'ca.key'} is not an ECDSA key made by this tool")
    cert_path, key_path = directory / f"{name}.pem", directory / f"{name}.key"
    if cert_path.exists() or key_path.exists():
        raise CertError(f"{cert_path} or {key_path} exists; not replaced")
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName([
                x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .sign(ca_key, hashes.SHA256()))
    _write_private(key_path, _key_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="placecell-certs",
        description="Make a site's certificate authority and the identities (robots, "
                    "operators, viewers, routers) that zenoh's access control names "
                    "by their certificates' common names.")
    sub = parser.add_subparsers(dest="command", required=True)
    ca = sub.add_parser("ca", help="make the site's CA (ca.pem, ca.key) in DIR")
    ca.add_argument("dir", type=Path)
    ca.add_argument("--days", type=int, default=3650)
    one = sub.add_parser("issue", help="make NAME.pem and NAME.key signed by DIR's CA")
    one.add_argument("dir", type=Path)
    one.add_argument("name", nargs="+", help="identity names (certificate common names)")
    one.add_argument("--days", type=int, default=825)
    args = parser.parse_args(argv)
    try:
        if args.command == "ca":
            print(make_ca(args.dir, days=args.days))
        else:
            for name in args.name:
                cert, key = issue(args.dir, name, days=args.days)
                print(f"{cert} {key}")
    except (CertError, OSError) as e:
        print(f"placecell-certs: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
