"""The built documentation site works offline: every page, opened in headless
Chromium from a local server with every other host unreachable, renders all its
maths (no formula is left as raw TeX) and asks for nothing outside the machine.

    python .ci/check_site.py [SITE_DIR]     (default: site/, what `mkdocs build` wrote)

Needs Chromium (Debian: `apt-get install chromium`) and BeautifulSoup (installed
with the [docs] extra). Exit code 0 when every page passes, 1 otherwise, with a
line per problem.
"""

import functools
import http.server
import json
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import urllib.parse

from bs4 import BeautifulSoup

LOCAL_HOSTS = {"127.0.0.1", "localhost"}
# Where a $ or a backslash is code, not maths.
SKIPPED = (
    "code, pre, script, style, .katex, .highlight, .highlight-ipynb, "
    ".jp-CodeCell .jp-InputArea"
)
# TeX left in the text of a page: a $...$ or $$...$$ holding a command or a
# sub/superscript, or \( \) \[ \] delimiters.
RAW_TEX = re.compile(r"\$\$?[^$]*?(\\[A-Za-z]+|[_^])[^$]*?\$|\\\(|\\\)|\\\[|\\\]")


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    sys.exit("check_site: no Chromium found (apt-get install chromium)")


def _serve(site: pathlib.Path) -> http.server.ThreadingHTTPServer:
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    handler = functools.partial(Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _open(url: str, folder: pathlib.Path) -> tuple[str, set[str]]:
    """The page's DOM after its scripts ran, and the hosts it asked for."""
    net_log = folder / "net.json"
    out = subprocess.run(
        [
            _chromium(),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-domain-reliability",
            "--disable-sync",
            f"--user-data-dir={folder / 'profile'}",
            # every name but the local server's fails to resolve: offline
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
            f"--log-net-log={net_log}",
            "--virtual-time-budget=10000",
            "--dump-dom",
            url,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    if out.returncode != 0:
        raise RuntimeError(f"chromium failed on {url}: {out.stderr[-2000:]}")
    return out.stdout, _hosts_asked(net_log)


def _hosts_asked(net_log: pathlib.Path) -> set[str]:
    """The hosts, other than the local server, of the requests the page made (from
    Chromium's net log: the jobs with the page as initiator; the browser's own
    requests, with none, are not the site's)."""
    text = net_log.read_text(errors="replace").rstrip()
    try:
        log = json.loads(text)
    except json.JSONDecodeError:  # the log of a browser that exited mid-write
        log = json.loads(text.rstrip(",") + "]}")
    types = {number: name for name, number in log["constants"]["logEventTypes"].items()}
    hosts = set()
    for event in log["events"]:
        params = event.get("params", {})
        if types.get(event["type"]) != "URL_REQUEST_START_JOB" or "url" not in params:
            continue
        if params.get("initiator", "not an origin") == "not an origin":
            continue  # the browser's own, or the page itself
        hosts.add(urllib.parse.urlsplit(params["url"]).hostname)
    return {h for h in hosts if h} - LOCAL_HOSTS


def problems_of(dom: str) -> list[str]:
    """What is wrong with a rendered page: maths left unrendered."""
    soup = BeautifulSoup(dom, "html.parser")
    found = []
    for element in soup.select(".arithmatex"):
        if not element.select(".katex"):
            found.append(f"unrendered formula: {element.get_text()[:80]!r}")
    content = soup.select_one("article") or soup.body or soup
    for tag in content.select(SKIPPED):
        tag.decompose()
    for match in RAW_TEX.finditer(content.get_text()):
        found.append(f"raw TeX left in the text: {match.group(0)[:80]!r}")
    return found


def check(site: pathlib.Path) -> list[str]:
    pages = sorted(site.rglob("*.html"))
    if not pages:
        return [f"no pages in {site}: build the site first (mkdocs build --strict)"]
    server = _serve(site)
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    failures = []
    rendered = 0
    try:
        for page in pages:
            relative = page.relative_to(site).as_posix()
            with tempfile.TemporaryDirectory() as folder:
                dom, hosts = _open(base + relative, pathlib.Path(folder))
            rendered += dom.count('class="katex"')
            failures += [f"{relative}: asked for {h}" for h in sorted(hosts)]
            failures += [f"{relative}: {p}" for p in problems_of(dom)]
    finally:
        server.shutdown()
    if rendered == 0:
        failures.append("no page has a formula rendered by KaTeX")
    print(json.dumps({"pages": len(pages), "formulas_rendered": rendered}), flush=True)
    return failures


if __name__ == "__main__":
    site = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "site")
    failures = check(site)
    for line in failures:
        print(line)
    sys.exit(1 if failures else 0)
