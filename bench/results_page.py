"""The one place that writes a generated block into bench/RESULTS.md.

A block sits between <!-- bench:NAME:begin --> and <!-- bench:NAME:end -->;
the benchmarks' table printers (update-results.py,
update-results-distributed.py) replace its content and leave the rest of the
page alone. A missing page or missing markers is reported, not an error.
"""
import os
import subprocess
import sys
import time


def result_meta(benchmark):
    """The fields every bench/results/*.json opens with: the benchmark's
    name, the date, the commit and the machine."""
    try:
        commit = subprocess.check_output(["git", "rev-parse", "--short", "HEAD"], text=True).strip()
    except Exception:
        commit = "?"
    cpu = "?"
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    return {"benchmark": benchmark, "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "commit": commit, "machine": {"cpu": cpu, "cores": os.cpu_count()}}


def replace_block(path, begin, end, body, who):
    try:
        with open(path) as f:
            page = f.read()
    except FileNotFoundError:
        print(f"{who}: {path} does not exist; results page not updated", file=sys.stderr)
        return
    i, j = page.find(begin), page.find(end)
    if i < 0 or j < 0 or j < i:
        print(f"{who}: {path} has no {begin} ... {end} block; results page not updated",
              file=sys.stderr)
        return
    new = page[:i + len(begin)] + "\n" + body + "\n" + page[j:]
    if new != page:
        tmp = path + ".tmp"
        with open(tmp, "w") as f:
            f.write(new)
        os.replace(tmp, path)
        print(f"{who}: updated {path}", file=sys.stderr)


def latest_result(results_dir, benchmark, who):
    """The newest bench/results/*.json whose "benchmark" is `benchmark`
    (by its "date"), or None; unreadable files are reported and skipped."""
    import glob
    import json
    best = None
    for path in sorted(glob.glob(os.path.join(results_dir, "*.json"))):
        try:
            with open(path) as f:
                data = json.load(f)
        except (OSError, ValueError) as e:
            print(f"{who}: skipping {path}: {e}", file=sys.stderr)
            continue
        if isinstance(data, dict) and data.get("benchmark") == benchmark:
            if best is None or data.get("date", "") > best.get("date", ""):
                best = data
    return best
