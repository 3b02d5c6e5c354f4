"""The TLS of a secure deployment: a local CA and the router's certificate, signed by it."""

from __future__ import annotations

import datetime
import ipaddress
from collections.abc import Sequence
from typing import Any

TLS_DIRECTORY = "tls"
CA_CERTIFICATE = "ca.pem"
ROUTER_CERTIFICATE = "router.pem"
ROUTER_KEY = "router-key.pem"
CERTIFICATE_DAYS = 365
TLS_NAMES = ("localhost", "127.0.0.1")
"""Names the router's certificate is valid for by default (``--tls-name`` adds more)."""


def certificates(names: Sequence[str]) -> dict[str, str]:
    """A fresh local CA (its key is not kept) and the router's key and certificate, signed by it,
    valid for ``names`` (the first its common name): PEM text by file name (:data:`CA_CERTIFICATE`,
    :data:`ROUTER_CERTIFICATE`, :data:`ROUTER_KEY`)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.UTC)
    valid_until = now + datetime.timedelta(days=CERTIFICATE_DAYS)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "invent-zenoh local CA")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(valid_until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                key_cert_sign=True,
                crl_sign=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    router_key = ec.generate_private_key(ec.SECP256R1())
    router = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, names[0])]))
        .issuer_name(ca_name)
        .public_key(router_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(valid_until)
        .add_extension(x509.SubjectAlternativeName([_general_name(name) for name in names]), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    return {
        CA_CERTIFICATE: ca.public_bytes(serialization.Encoding.PEM).decode(),
        ROUTER_CERTIFICATE: router.public_bytes(serialization.Encoding.PEM).decode(),
        ROUTER_KEY: router_key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        ).decode(),
    }


def _general_name(name: str) -> Any:
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(name))
    except ValueError:
        return x509.DNSName(name)
