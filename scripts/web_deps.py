#!/usr/bin/python3
"""Installs a folder's pinned npm dependencies into DIR/node_modules, as `npm ci` would: the
web viewer's (web/) and the splat converters the interop tests run (tests/splat_interop/).

Written here rather than run through npm: the viewer has one dependency (gl-matrix), and
Debian's npm brings ~300 packages onto a fresh machine for it. This reads DIR/package-lock.json
(lockfile v3), downloads each package's tarball from the npm registry, checks it against the
lockfile's `integrity` (SRI sha512, as npm does), and unpacks it. No install scripts are run.
Nothing is fetched at run time: hvdb-server serves the viewer's files from web/node_modules.

    /usr/bin/python3 scripts/web_deps.py [DIR]   (default: web/ beside this script)

Exit status 1, with the reason, on a network error or a tarball that does not match.
"""
import base64
import hashlib
import io
import json
import os
import shutil
import sys
import tarfile
import urllib.request

REGISTRY = os.environ.get("HVDB_NPM_REGISTRY", "https://registry.npmjs.org")


def tarball_url(name, version):
    base = name.split("/")[-1]  # @scope/pkg -> pkg
    return f"{REGISTRY}/{name}/-/{base}-{version}.tgz"


def check_integrity(data, integrity, name):
    algo, _, want = integrity.partition("-")
    if algo not in ("sha512", "sha384", "sha256"):
        raise SystemExit(f"web_deps: {name}: unsupported integrity '{algo}' in package-lock.json")
    got = base64.b64encode(hashlib.new(algo, data).digest()).decode()
    if got != want:
        raise SystemExit(f"web_deps: {name}: the downloaded tarball does not match package-lock.json "
                         f"({algo} {got} != {want}); not installed")


def unpack(data, dest):
    tmp = dest + ".tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        for m in tar.getmembers():
            # npm tarballs hold one top folder ("package/"); nothing may leave it.
            parts = m.name.split("/", 1)
            if len(parts) < 2 or not (m.isfile() or m.isdir()):
                continue
            rel = os.path.normpath(parts[1])
            if rel.startswith("..") or os.path.isabs(rel):
                raise SystemExit(f"web_deps: {m.name}: a path outside the package")
            target = os.path.join(tmp, rel)
            if m.isdir():
                os.makedirs(target, exist_ok=True)
                continue
            os.makedirs(os.path.dirname(target), exist_ok=True)
            with tar.extractfile(m) as src, open(target, "wb") as out:
                shutil.copyfileobj(src, out)
    shutil.rmtree(dest, ignore_errors=True)
    os.replace(tmp, dest)


def main():
    web = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "web")
    with open(os.path.join(web, "package-lock.json")) as f:
        lock = json.load(f)
    if lock.get("lockfileVersion") not in (2, 3):
        raise SystemExit("web_deps: web/package-lock.json: lockfile version 2 or 3 expected")
    modules = os.path.join(web, "node_modules")
    os.makedirs(modules, exist_ok=True)
    for path, pkg in sorted(lock.get("packages", {}).items()):
        if not path.startswith("node_modules/"):
            continue
        name = path[len("node_modules/"):]
        url = pkg.get("resolved") or tarball_url(name, pkg["version"])
        try:
            with urllib.request.urlopen(url, timeout=60) as r:
                data = r.read()
        except OSError as e:
            raise SystemExit(f"web_deps: cannot download {url}: {e}")
        check_integrity(data, pkg["integrity"], name)
        unpack(data, os.path.join(modules, name))
        print(f"web_deps: {name} {pkg['version']} ({len(data)} bytes, integrity checked)")
    # The marker setup.sh compares with the lockfile (npm keeps the same file).
    shutil.copyfile(os.path.join(web, "package-lock.json"), os.path.join(modules, ".package-lock.json"))


if __name__ == "__main__":
    main()
