"""Certificates for the authenticated link's tests, made with ``cryptography``: a cell CA, the
hub's certificate (naming 127.0.0.1 and localhost) and one per node, CN = the node's name, as
README "In a real cell" makes them with openssl."""

from __future__ import annotations

import datetime
import ipaddress
import shutil
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "zenoh-cell"


def _write(base: Path, key: ec.EllipticCurvePrivateKey, cert: x509.Certificate) -> None:
    base.with_suffix(".key").write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption()))
    base.with_suffix(".pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def make_certs(folder: Path, names: tuple[str, ...], ca: str = "ca") -> None:
    """``folder/{ca}.pem|.key`` (a CA) and ``folder/{name}.pem|.key`` signed by it, CN=name."""
    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    valid = (now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=1))
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"{ca} of the cell")])
    ca_cert = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
               .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(valid[0]).not_valid_after(valid[1])
               .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
               .add_extension(x509.KeyUsage(
                   digital_signature=True, key_cert_sign=True, crl_sign=True,
                   content_commitment=False, key_encipherment=False, data_encipherment=False,
                   key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
               .sign(ca_key, hashes.SHA256()))
    _write(folder / ca, ca_key, ca_cert)
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
                .issuer_name(ca_name).public_key(key.public_key())
                .serial_number(x509.random_serial_number())
                .not_valid_before(valid[0]).not_valid_after(valid[1])
                .add_extension(x509.SubjectAlternativeName([
                    x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                    critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]),
                               critical=False)
                .sign(ca_key, hashes.SHA256()))
        _write(folder / name, key, cert)


def cell_folder(tmp: Path) -> Path:
    """The shipped example configs (examples/zenoh-cell) beside fresh certificates in certs/."""
    cell = tmp / "cell"
    shutil.copytree(EXAMPLES, cell)
    make_certs(cell / "certs", ("hub", "robot", "tracker"))
    return cell
