"""``linemap keys``: make an Ed25519 signing key and sign kernel files (docs/design.md §7: signed kernels
only)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from shared.errors import LinemapError

__all__ = ["keys_app"]

keys_app = typer.Typer(help="Ed25519 keys that sign kernel artifacts.", no_args_is_help=True)


@keys_app.command("generate")
def generate(
    out: Annotated[Path, typer.Option(help="Private key file to write (PEM, mode 0600).")] = Path(
        "linemap-signing.pem"
    ),
    force: Annotated[bool, typer.Option(help="Overwrite an existing key file.")] = False,
) -> None:
    """Write a new private key to OUT and print its public key (register that on the server and robots)."""
    from shared.signing import generate_keypair

    if out.exists() and not force:
        raise LinemapError(f"{out} exists already; pass --force to overwrite it")
    pair = generate_keypair()
    fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(pair.private_pem)
    typer.echo(f"private key: {out} (keep it secret)")
    typer.echo(f"key id:      {pair.key_id}")
    typer.echo(f"public key:  {pair.public_b64}")


@keys_app.command("sign")
def sign(
    file: Annotated[Path, typer.Argument(help="Kernel module file to sign.")],
    key: Annotated[Path, typer.Option(help="Private key file from `linemap keys generate`.")] = Path(
        "linemap-signing.pem"
    ),
) -> None:
    """Print the file's sha256 and the base64 signature over it (the upload's `signature` field)."""
    from shared.signing import load_private_key, sha256_hex, sign_digest

    try:
        data, pem = file.read_bytes(), key.read_bytes()
    except OSError as exc:
        raise LinemapError(f"cannot read {exc.filename}: {exc.strerror}") from None
    digest = sha256_hex(data)
    typer.echo(f"sha256:    {digest}")
    typer.echo(f"signature: {sign_digest(load_private_key(pem), digest)}")
