"""A census of Mitsuba scene files: which features they use, which invrender reads, how many load,
and whether those that load render like Mitsuba 3.

    python bench/census.py FOLDER [FOLDER ...] [--spp 128] [--timeout 300] [--no-render] [--json PATH]

The population is the ``*.xml`` files under the folders (recursively) that Mitsuba 3 itself loads as
they are (``mi.load_file``); the others are counted apart by the reason Mitsuba gives: a fragment
(a reference to an object defined elsewhere), missing data (a mesh, texture or folder the checkout
lacks), an undefined ``$parameter``, or another refusal. For the population it prints:

- per feature (each ``<element type="...">`` plugin, and the syntax: ``<path>``, ``<include>``,
  ``<default>``/``$name`` parameters, ``<ref>``, spectra by kind, Mitsuba 0.x files, ...) how many
  files use it (counting what their includes hold), whether invrender's reader supports it (from
  :mod:`invrender.scene.formats.mitsuba.subset`, the reader's own tables and the registries) and
  how many of those files load in invrender;
- for each file that loads, its channel means against Mitsuba's render at 64x64 with the file's
  integrator and settings (as ``scene.defaults`` holds them for invrender; Mitsuba's own reading
  of the file for Mitsuba; a file without ``<integrator>`` is rendered with Mitsuba's default,
  ``path`` at max_depth -1, by both), the same spp both, in ``--passes`` independent passes whose
  per-pixel spread gives the standard error of each mean; where the combined noise exceeds
  ``--noise`` the file is rendered again at 4x the spp (up to ``--max-spp``). Pass: every channel
  within ``--tolerance`` (2%) of Mitsuba's;
- for the rest, the first blocker of each file (the first problem invrender's error names) and the
  count of every blocker over all files (each load error lists the first five problems and counts
  the others).

Both renderers see the film resized to 64x64 as if the file said so: invrender through
``load_scene(..., resolution=(64, 64))``, Mitsuba through its film's ``size`` parameter, with its
camera's ``x_fov`` set to invrender's at 64x64 (Mitsuba keeps the x-fov it computed for the file's
film; for a ``fov_axis`` y or smaller/larger and for ``focal_length`` that differs at another
aspect). That the two read the same field of view is checked at the file's own film size, where
Mitsuba's ``x_fov`` and invrender's camera must agree (the ``fov check`` column). Reconstruction
filters: invrender always uses a box; Mitsuba the file's (Gaussian in most), which moves the
channel means by little at 64x64 but not by nothing: the comparison is of the files as written.

Each file runs in a worker process with a time limit (``--timeout``, seconds); a file over it
counts as timed out. ``--no-render`` stops after loading (the census without the comparison).
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import math
import multiprocessing as mp
import re
import sys
import time
import traceback
import warnings
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from _measure import Results, add_json_option  # noqa: E402

RESOLUTION = 64


# ----------------------------------------------------------------------------- static scan


def scan(path: Path) -> set[str]:
    """The features a file uses, its includes' included (missing or unreadable ones skipped);
    ``$name`` in a plugin type replaced by the ``<default>`` value the file gives."""
    features: set[str] = set()
    _scan(path, features, set(), {})
    return features


def _scan(path: Path, features: set, seen: set, params: dict) -> None:
    path = path.resolve()
    if path in seen or not path.is_file():
        return
    seen.add(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        features.add("malformed XML")
        return
    version = root.get("version", "")
    if root.tag == "scene" and version.split(".")[0].isdigit() and int(version.split(".")[0]) < 1:
        features.add("Mitsuba 0.x file (upgraded)")
    for node in root.iter("default"):
        params.setdefault(node.get("name", ""), node.get("value", ""))
    for node in root.iter():
        if any("$" in v for v in node.attrib.values()):
            features.add("$name parameters")
        tag = node.tag
        if tag == "include":
            features.add("<include>")
            name = node.get("filename", "")
            if name and "$" not in name:
                _scan(path.parent / name, features, seen, params)
        elif tag == "spectrum" and "type" not in node.attrib:
            value = node.get("value", "")
            kind = "file" if "filename" in node.attrib else "wavelength:value list" if ":" in value else "constant"
            features.add(f"<spectrum> {kind}")
        elif "type" in node.attrib and tag != "scene":
            kind = re.sub(r"\$(\w+)", lambda m: params.get(m.group(1), m.group(0)), node.get("type"))
            features.add(f'<{tag} type="{kind}">')
        elif tag in ("path", "default", "ref", "alias", "medium", "phase", "volume", "shapegroup"):
            features.add(f"<{tag}>")


def feature_supported(feature: str, subset) -> bool:
    """Does invrender's reader take ``feature`` (as :func:`scan` names it)? From the reader's tables."""
    m = re.match(r'<(\w+) type="([^"]*)">$', feature)
    if m:
        return subset.plugin_supported(m.group(1), m.group(2).lower())
    m = re.match(r"<(\w+)>", feature)
    if m:
        return subset.element_supported(m.group(1))
    if feature.startswith("Mitsuba 0.x"):
        return subset.NEWEST_MAJOR >= 3  # the reader upgrades older versions
    if feature == "$name parameters":
        return subset.element_supported("default")
    return False


# ----------------------------------------------------------------------------- the worker


def mitsuba_reason(message: str) -> str:
    """Why Mitsuba refuses a file, as the census counts it."""
    if "unresolved reference" in message:
        return "fragment (refers to an object defined elsewhere)"
    if "undefined parameter" in message:
        return "undefined $parameter"
    if re.search(r"not found|No such file|does not exist|I/O error|could not be found|unable to open", message, re.I):
        return "missing data (a file or folder the checkout lacks)"
    return "Mitsuba refuses it"


def problems(message: str) -> list[str]:
    """The problems a load error names (one, or the numbered list of a several-problem error)."""
    listed = re.split(r"; \(\d+\) |: \(1\) ", message)
    if len(listed) > 1 and re.search(r"\d+ problems stop this scene from loading", listed[0]):
        items = listed[1:]
        items[-1] = re.sub(r"[;,]? (\.\.\. )?and \d+ more.*$", "", items[-1])
        return items
    return [message]


def blocker_key(problem: str) -> str:
    """A problem without its file, line and values: what is counted across files."""
    text = re.sub(r"^\S+?:\d+: ", "", problem.strip())
    text = re.sub(r"^\S+\.xml: ", "", text)
    text = re.sub(r" \((supported|ids in this file|known): [^)]*\)?", "", text)
    text = re.sub(r", got .*$", "", text)
    text = re.sub(r"\s+", " ", text)
    return text[:120]


def _worker(conn, args) -> None:
    warnings.simplefilter("ignore")
    faulthandler.enable()  # a crash of either renderer prints where it happened to the census's stderr
    import mitsuba_ref

    import invrender as ir
    from invrender.errors import SceneError

    if not mitsuba_ref.available():
        conn.send({"fatal": "Mitsuba 3 (llvm_ad_rgb) is not available"})
        return
    mi, _ = mitsuba_ref._require()
    conn.send({"ready": True})
    while True:
        path = conn.recv()
        if path is None:
            return
        try:
            conn.send(measure(Path(path), args, mi, mitsuba_ref, ir, SceneError))
        except Exception as e:  # a crash of either renderer is a finding, not the end of the census
            conn.send({"crash": f"{type(e).__name__}: {e}".replace("\n", " ")[:300], "trace": traceback.format_exc()[-800:]})


def measure(path: Path, args, mi, mitsuba_ref, ir, SceneError) -> dict:
    out: dict = {}
    try:
        with mitsuba_ref.whole_pool():  # Mitsuba loads in parallel: with an empty pool its EXR reads waited minutes
            mscene = mi.load_file(str(path))
    except Exception as e:
        return {"mitsuba_error": str(e).replace("\n", " ")[:400]}
    try:
        at_file = ir.load_scene(path)
        scene = ir.load_scene(path, resolution=(args.resolution, args.resolution))
    except SceneError as e:
        return {"blocked": str(e)}
    except Exception as e:
        return {"blocked": f"crash while loading: {type(e).__name__}: {e}".replace("\n", " ")[:300]}
    out["loaded"] = True
    out["defaults"] = dict(scene.defaults)
    if args.no_render:
        return out
    params = mi.traverse(mscene)
    sensor = mscene.sensors()[0]
    film = sensor.film()
    keys = list(params.keys())
    fov_key = next((k for k in keys if k.endswith("x_fov")), None)
    size_key = next((k for k in keys if k.endswith("film.size")), None)
    camera = at_file.camera
    if fov_key is not None:
        w0, h0 = (int(x) for x in film.size())
        tx, _ = camera.tan_half_fov(w0, h0)
        mine = math.degrees(2 * math.atan(tx))
        theirs = float(params[fov_key][0]) if hasattr(params[fov_key], "__len__") else float(params[fov_key])
        out["fov_check"] = [mine, theirs]
        tx64, _ = scene.camera.tan_half_fov(scene.width, scene.height)
        params[fov_key] = math.degrees(2 * math.atan(tx64))
    if size_key is None:
        out["crash"] = "Mitsuba's film has no size parameter"
        return out
    size = mi.ScalarVector2u(args.resolution, args.resolution)
    params[size_key] = size
    crop = size_key.replace("film.size", "film.crop_size")
    if crop in params.keys():
        params[crop] = size
    params.update()

    settings = {}
    if "integrator" not in scene.defaults:  # Mitsuba's default integrator: path, max_depth -1
        settings = {"integrator": "path", "max_depth": -1}
    out["settings"] = {**{k: v for k, v in scene.defaults.items() if k != "spp"}, **settings}
    spp = args.spp
    while True:
        passes = args.passes
        per = max(1, spp // passes)
        t0 = time.perf_counter()
        mine = [ir.render(scene, spp=per, seed=1000 + k, progress=False, **settings).double().cpu().numpy() for k in range(passes)]
        t1 = time.perf_counter()
        theirs = [mitsuba_ref.render(mscene, per, seed=k).astype("float64") for k in range(passes)]
        t2 = time.perf_counter()
        m_ir, se_ir = _means(mine)
        m_mi, se_mi = _means(theirs)
        noise = [math.hypot(a, b) / max(abs(c), 1e-12) * 100 for a, b, c in zip(se_ir, se_mi, m_mi)]
        out.update(spp=per * passes, invrender=m_ir, mitsuba=m_mi, se_invrender=se_ir, se_mitsuba=se_mi, noise_pct=noise,
                   seconds_invrender=t1 - t0, seconds_mitsuba=t2 - t1)
        off = any(abs(a / b - 1) * 100 > args.tolerance for a, b in zip(m_ir, m_mi) if abs(b) > 1e-12)
        if (max(noise) <= args.noise and not off) or spp * 4 > args.max_spp or t1 - t0 > args.timeout / 8:
            break  # a file off by more than the tolerance is rendered again too: a few passes' spread misses rare bright paths
        spp *= 4
    return out


def _means(images) -> tuple[list[float], list[float]]:
    """Channel means of the passes together and their standard errors (from each pixel's spread
    over the passes)."""
    import numpy as np

    stack = np.stack([np.asarray(i)[..., :3] for i in images])  # (passes, H, W, 3)
    k = stack.shape[0]
    mean = stack.mean(axis=(0, 1, 2))
    if k < 2:
        return mean.tolist(), [math.nan] * 3
    var = stack.var(axis=0, ddof=1) / k  # variance of each pixel's mean over the passes
    n = stack.shape[1] * stack.shape[2]
    se = np.sqrt(var.sum(axis=(0, 1))) / n
    return mean.tolist(), se.tolist()


class Worker:
    """A worker process measuring one file at a time, restarted after a file runs over the time limit."""

    def __init__(self, args):
        self.args = args
        self.ctx = mp.get_context("spawn")
        self.proc = None

    def start(self):
        here, there = self.ctx.Pipe()
        self.conn = here
        self.proc = self.ctx.Process(target=_worker, args=(there, self.args), daemon=True)
        self.proc.start()
        if not self.conn.poll(300):
            raise SystemExit("census: the worker did not start within 300 s")
        hello = self.conn.recv()
        if "fatal" in hello:
            raise SystemExit(f"census: {hello['fatal']}")

    def run(self, path: Path) -> dict:
        if self.proc is None or not self.proc.is_alive():
            self.start()
        self.conn.send(str(path))
        if self.conn.poll(self.args.timeout):
            try:
                return self.conn.recv()
            except EOFError:
                pass
        else:
            self.stop()
            return {"timeout": True}
        self.stop()
        return {"crash": "the worker process died"}

    def stop(self):
        if self.proc is not None and self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.proc = None

    def close(self):
        if self.proc is not None and self.proc.is_alive():
            self.conn.send(None)
            self.proc.join(10)
        self.stop()


# ----------------------------------------------------------------------------- the report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--resolution", type=int, default=RESOLUTION)
    p.add_argument("--spp", type=int, default=64, help="samples per pixel of each renderer (split over the passes)")
    p.add_argument("--passes", type=int, default=4, help="independent passes whose spread gives the noise")
    p.add_argument("--noise", type=float, default=0.7, help="combined noise (%%) above which a file is rendered again at 4x spp (as is a file off by more than --tolerance)")
    p.add_argument("--max-spp", type=int, default=2048)
    p.add_argument("--tolerance", type=float, default=2.0, help="pass: every channel within this many percent of Mitsuba's")
    p.add_argument("--timeout", type=float, default=300.0, help="seconds per file")
    p.add_argument("--no-render", action="store_true", help="load only: no comparison with Mitsuba's renders")
    p.add_argument("--only", default=None, help="only the files whose path contains this string")
    p.add_argument("--raw", type=Path, default=None, help="also write every file's measurement here (JSON), for --from-raw")
    p.add_argument("--from-raw", type=Path, default=None, help="report the measurements of an earlier --raw file instead of measuring")
    add_json_option(p)
    args = p.parse_args(argv)

    from tqdm import tqdm

    from invrender.scene.formats.mitsuba import subset

    files = sorted({f.resolve() for folder in args.folders for f in folder.rglob("*.xml")})
    if args.only:
        files = [f for f in files if args.only in str(f)]
    if not files:
        print(f"census: no .xml files under {', '.join(map(str, args.folders))}", file=sys.stderr)
        return 2
    names = {f: _short(f, args.folders) for f in files}
    res = Results("census", f"Census of {len(files)} Mitsuba scene files")  # the commit and its state as the census starts
    results: dict[Path, dict] = {}
    start = time.perf_counter()
    if args.from_raw is not None:
        raw = json.loads(args.from_raw.read_text())
        results = {f: raw[str(f)] for f in files if str(f) in raw}
        res.note(f"The per-file measurements of an earlier run (--raw), re-reported: {args.from_raw}")
        files = [f for f in files if f in results]
    else:
        worker = Worker(args)
        try:
            bar = tqdm(files, unit="file", dynamic_ncols=True)
            for f in bar:
                bar.set_postfix_str(names[f][-40:])
                results[f] = r = worker.run(f)
                bar.write(f"{names[f]}: {_one_line(r, args.tolerance)}")
        finally:
            worker.close()
        if args.raw is not None:
            args.raw.write_text(json.dumps({str(f): r for f, r in results.items()}, indent=1))

    refused = {f: r for f, r in results.items() if "mitsuba_error" in r}
    population = [f for f in files if f not in refused]
    loaded = [f for f in population if results[f].get("loaded")]
    print(f"\n{len(files)} files under {', '.join(map(str, args.folders))}: Mitsuba 3 loads {len(population)} as they are "
          f"(the population); invrender loads {len(loaded)} of them.")

    rows = res.table("Files Mitsuba 3 does not load as they are (not in the population)", ["reason", "files"])
    for reason, n in Counter(mitsuba_reason(r["mitsuba_error"]) for r in refused.values()).most_common():
        rows.append([reason, n])
    _print_table(res.tables[-1])

    features = {f: scan(f) for f in population}
    use = Counter(x for fs in features.values() for x in fs)
    rows = res.table(f"Features of the {len(population)} files Mitsuba loads", ["feature", "files", "invrender reads it", "of those, load in invrender"],
                     note="Support from invrender's reader tables (invrender/scene/formats/mitsuba/subset.py) and registries; a file counts a feature its includes use.")
    for feat, n in sorted(use.items(), key=lambda t: (-t[1], t[0])):
        ok = sum(1 for f in population if feat in features[f] and results[f].get("loaded"))
        rows.append([_code(feat), n, "yes" if feature_supported(feat, subset) else "no", ok])
    _print_table(res.tables[-1])

    blocked = [f for f in population if not results[f].get("loaded")]
    first, every = Counter(), Counter()
    for f in blocked:
        r = results[f]
        if "blocked" in r:
            listed = [blocker_key(x) for x in problems(r["blocked"])]
            first[listed[0]] += 1
            every.update(set(listed))
        else:
            key = "timed out" if r.get("timeout") else f"crash: {r.get('crash', '?')[:80]}"
            first[key] += 1
            every[key] += 1
    rows = res.table(f"What blocks the other {len(blocked)}: the first blocker of each file, and files naming it at all", ["blocker", "first blocker of", "named by"])
    for key, n in sorted(every.items(), key=lambda t: (-first[t[0]], -t[1], t[0])):
        rows.append([_code(key), first[key], n])
    _print_table(res.tables[-1])
    rows = res.table("Blocked files", ["file", "first blocker"])
    for f in blocked:
        r = results[f]
        rows.append([names[f], _code(blocker_key(problems(r["blocked"])[0])) if "blocked" in r else ("timed out" if r.get("timeout") else r.get("crash", "?")[:120])])
    _print_table(res.tables[-1])

    passed = 0
    if not args.no_render:
        rows = res.table(
            f"The {len(loaded)} files that load: channel means at {args.resolution}x{args.resolution}, invrender vs Mitsuba 3 ({mitsuba_label()}), pass within {args.tolerance:g}% per channel",
            ["file", "settings", "spp", "fov check (deg)", "invrender R G B", "Mitsuba R G B", "diff % R G B", "noise % (1 sigma)", "pass", "s (invrender / Mitsuba)"],
            note="noise: the standard error of the difference of the means, from each pixel's spread over the passes, in % of Mitsuba's mean.")
        for f in loaded:
            r = results[f]
            if "invrender" not in r:
                rows.append([names[f], "", "", "", "", "", "", "", "crash: " + r.get("crash", "?")[:100], ""])
                continue
            diff = differences(r)
            ok = all(abs(d) <= args.tolerance for d in diff)
            passed += ok
            fov = r.get("fov_check")
            fov_cell = "" if fov is None else f"{fov[0]:.3f} / {fov[1]:.3f}" + ("" if abs(fov[0] - fov[1]) < 1e-2 else " MISMATCH")
            settings = ", ".join(f"{k}={v}" for k, v in r["settings"].items())
            known = next((why for key, why in MITSUBA_DIFFERS.items() if names[f].endswith(key)), None)
            rows.append([names[f], settings, r["spp"], fov_cell, _triple(r["invrender"], 4), _triple(r["mitsuba"], 4), _triple(diff, 2), _triple(r["noise_pct"], 2),
                         "yes" if ok else ("no: " + known if known else "NO"), f"{r['seconds_invrender']:.1f} / {r['seconds_mitsuba']:.1f}"])
        _print_table(res.tables[-1])
    summary = (f"{len(files)} files; Mitsuba 3 loads {len(population)} (the population); invrender loads {len(loaded)}"
               + ("" if args.no_render else f"; {passed} of those match Mitsuba within {args.tolerance:g}% in every channel mean"))
    res.note(summary)
    res.note(f"{sum(1 for r in results.values() if r.get('timeout'))} file(s) timed out (limit {args.timeout:g} s); total {time.perf_counter() - start:.0f} s")
    print("\n" + summary)
    res.write(args.json)
    return 0


#: files on which Mitsuba 3.9.1 computes something else than its own documentation and the
#: rendering equation say, which invrender does not copy (the pages that show it):
MITSUBA_DIFFERS = {
    "docs/scenes/bsdf_blendbsdf.xml": "Mitsuba mixes a delta sample's weight with the other material's density (biased; docs/rendering.md, blends)",
    "scenes/hello.xml": "Mitsuba's direct with emitter_samples 4 counts each point light 4 times (mitsuba3 #1861; docs/rendering.md, direct)",
}


def differences(r: dict) -> list[float]:
    """invrender's channel means against Mitsuba's, in % (0 where both are black, inf where only Mitsuba's is)."""
    return [(a - b) / b * 100 if abs(b) > 1e-9 else (0.0 if abs(a) < 1e-9 else math.inf) for a, b in zip(r["invrender"], r["mitsuba"])]


def _one_line(r: dict, tolerance: float) -> str:
    """A file's outcome as the progress log shows it."""
    if "mitsuba_error" in r:
        return f"Mitsuba refuses it ({mitsuba_reason(r['mitsuba_error'])})"
    if "blocked" in r:
        return "blocked: " + blocker_key(problems(r["blocked"])[0])
    if "invrender" in r:
        diff = differences(r)
        verdict = "pass" if all(abs(d) <= tolerance for d in diff) else "OFF"
        return f"{verdict}: diff % {_triple(diff, 2)}, noise % {_triple(r['noise_pct'], 2)}, {r['spp']} spp"
    return "loads" if r.get("loaded") else ("timed out" if r.get("timeout") else f"crash: {r.get('crash', '?')[:120]}")


def mitsuba_label() -> str:
    import mitsuba_ref

    return mitsuba_ref.label()


def _short(f: Path, folders) -> str:
    for folder in folders:
        try:
            return f"{folder.resolve().name}/{f.relative_to(folder.resolve())}"
        except ValueError:
            continue
    return str(f)


def _code(text: str) -> str:
    """Text with XML in it as Markdown code (so that a page shows the <element> rather than swallowing it)."""
    return f"`{text}`" if "<" in text and "`" not in text else text


def _triple(values, digits: int) -> str:
    return " ".join(f"{v:.{digits}f}" for v in values)


def _print_table(table: dict) -> None:
    print(f"\n{table['title']}\n")
    print("| " + " | ".join(table["columns"]) + " |")
    print("|" + "---|" * len(table["columns"]))
    for row in table["rows"]:
        print("| " + " | ".join(str(c) for c in row) + " |")
    if table.get("note"):
        print(f"\n{table['note']}")


if __name__ == "__main__":
    sys.exit(main())
