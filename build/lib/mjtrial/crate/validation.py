"""Validating a crate offline with `rocrate-validator` (PyPI `roc-validator`).

The validator fetches the JSON-LD contexts a crate names over HTTP, through a `requests_cache`
session (`rocrate_validator.utils.http.HttpRequester`) that has an offline mode serving only
what its cache holds. `seed_cache` puts the vendored contexts (`contexts/`, their sources in
`contexts/contexts.json`) into that cache through the validator's own session, as responses
to the URLs they are published at: a transport adapter mounted for those URLs answers with
the files, and `requests_cache` stores the answers under its own keys (method, URL and body;
not the request's headers, so the validator's later `Accept` headers find them). The
validator then runs with `offline=True` on that cache and never opens a connection.

The validator is a test dependency (`pip install -e '.[test]'`); the pipeline does not need it.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

CONTEXTS_DIR = Path(__file__).resolve().parent / "contexts"
PROFILE = "provenance-run-crate-0.5"


@dataclass(frozen=True)
class Finding:
    """One issue the validator reports."""

    severity: str  # REQUIRED, RECOMMENDED, OPTIONAL
    profile: str
    check: str
    message: str
    entity: str | None

    def line(self) -> str:
        where = f" ({self.entity})" if self.entity else ""
        return f"{self.severity} {self.profile}: {self.check}: {self.message}{where}"


def context_documents() -> dict[str, bytes]:
    """The vendored contexts: URL -> bytes, each checked against its recorded sha256."""
    documents = {}
    for record in json.loads((CONTEXTS_DIR / "contexts.json").read_text(encoding="utf-8")):
        data = (CONTEXTS_DIR / record["file"]).read_bytes()
        if hashlib.sha256(data).hexdigest() != record["sha256"]:
            raise ValueError(f"{record['file']}: not the file contexts.json records")
        documents[record["url"]] = data
    return documents


def seed_cache(cache_path: Path) -> list[str]:
    """Put the vendored contexts into the validator's HTTP cache at `cache_path` (the cache's
    name: `requests_cache` adds `.sqlite`); returns the URLs it now answers offline."""
    # Imported here: the validator is a test dependency, and requests (Snakemake's) is
    # only needed to talk to its cache.
    import urllib3
    from requests.adapters import BaseAdapter, HTTPAdapter
    from rocrate_validator.utils.http import HttpRequester

    documents = context_documents()

    class Vendored(BaseAdapter):
        """Answers a GET of a vendored URL with the file, as the server would."""

        def send(self, request: Any, **kwargs: Any) -> Any:
            raw = urllib3.HTTPResponse(
                body=io.BytesIO(documents[request.url]),
                headers={"Content-Type": "application/ld+json"},
                status=200,
                preload_content=False,
                request_url=request.url,
            )
            return HTTPAdapter().build_response(request, raw)

        def close(self) -> None:
            pass

    Path(cache_path).parent.mkdir(parents=True, exist_ok=True)
    HttpRequester.initialize_cache(cache_path=str(cache_path), cache_max_age=-1, offline=False)
    session = HttpRequester().session
    for url in documents:
        session.mount(url, Vendored())
        response = session.get(url)
        if response.status_code != 200:
            raise RuntimeError(f"{url}: the cache did not take the vendored context")
    # Back to a session without the adapter, serving the cache only.
    HttpRequester.initialize_cache(cache_path=str(cache_path), cache_max_age=-1, offline=True)
    return list(documents)


def validate(
    crate: Path,
    *,
    cache_path: Path,
    severity: str = "REQUIRED",
    profile: str = PROFILE,
) -> list[Finding]:
    """Validate the crate (a folder or a zip) against `profile` at `severity` and above,
    offline, the cache at `cache_path` seeded with the vendored contexts first. Returns the
    findings; none means the crate conforms at that severity."""
    # Imported here: the validator is a test dependency (pip install -e '.[test]').
    from rocrate_validator import services
    from rocrate_validator.models import Severity, ValidationSettings

    seed_cache(cache_path)
    settings = ValidationSettings(
        rocrate_uri=str(crate),
        profile_identifier=profile,
        requirement_severity=Severity[severity],
        offline=True,
        cache_path=Path(cache_path),
    )
    result = services.validate(settings)
    findings = [
        Finding(
            severity=issue.severity.name,
            profile=issue.check.requirement.profile.identifier,
            check=issue.check.name,
            message=" ".join(str(issue.message).split()),
            entity=getattr(issue, "violatingEntity", None),
        )
        for issue in result.get_issues()
    ]
    return sorted(findings, key=lambda f: (f.severity, f.profile, f.check, str(f.entity)))
