#!/usr/bin/env python3
"""Runs README.md's shell blocks as a new user would, on a copy of this checkout.

    python3 tests/readme_guide.py [path/to/volrad]     # default: target/release/volrad

- The guide block (the one opening with the bare `volrad`): every `volrad` line, in order, as
  written (through bash, comments and all), then checks the files its comments promise. This
  includes what `cargo test`'s `readme::the_readme_guide_runs_as_written` leaves out for time:
  the path-traced reference, `bench albedo` and both `validate` lines. The `validate` lines
  run with `--quick` added (the same cases, views and report at CI size: 64-path references,
  4-sample renders): as written they take 10 minutes on 2 cores, a fifth of CI's time, and
  docs/validation.md's tables are what they make at full size.
- The service: the `volrad serve …` line (without its `&`), then every `curl` line of the block
  after it, each with `--fail` added and the README's placeholder ids (`3df3…` a scene,
  `6f0e…` a sky scene) replaced by the ids the service gave: the posted cloud's, and a sky
  scene (data/cloud-sky.toml) posted here. Every request must answer 2xx and the images must be
  PNGs.

Standard library only. Exits 1 naming the first command that failed.
"""

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ADDR = "127.0.0.1:8080"


def fail(message):
    print(f"readme_guide: {message}", file=sys.stderr)
    sys.exit(1)


def shell_blocks(markdown):
    """The fenced sh/bash blocks, each a list of logical lines (continuations joined)."""
    blocks = []
    for body in re.findall(r"```(?:sh|bash)\n(.*?)```", markdown, re.S):
        lines, pending = [], ""
        for line in body.splitlines():
            if line.rstrip().endswith("\\"):
                pending += line.rstrip()[:-1] + " "
                continue
            lines.append(pending + line)
            pending = ""
        blocks.append(lines)
    return blocks


def command_of(line):
    """The line without its trailing comment (a `#` after whitespace, outside quotes)."""
    quote = None
    for i, c in enumerate(line):
        if quote:
            quote = None if c == quote else quote
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].strip()
    return line.strip()


def run(command, cwd, env):
    start = time.time()
    done = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.time() - start
    if done.returncode != 0:
        fail(f"`{command}` exited {done.returncode} after {seconds:.0f} s:\n{done.stderr[-3000:]}")
    print(f"ok {seconds:6.1f} s  {command}", flush=True)
    return done.stdout, done.stderr


def copy_checkout(dest):
    """The tracked and untracked-but-not-ignored files of this checkout (what a clone holds)."""
    files = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, capture_output=True, check=True,
    ).stdout.decode().split("\0")
    for f in filter(None, files):
        src = os.path.join(ROOT, f)
        if os.path.isfile(src):
            os.makedirs(os.path.dirname(os.path.join(dest, f)) or dest, exist_ok=True)
            shutil.copy2(src, os.path.join(dest, f))


def get(path, timeout=10):
    with urllib.request.urlopen(f"http://{ADDR}{path}", timeout=timeout) as r:
        return r.status, r.read()


def wait_done(scene_id, limit_s=600):
    start = time.time()
    while time.time() - start < limit_s:
        state = json.loads(get(f"/v1/scenes/{scene_id}")[1])["state"]
        if state == "done":
            return
        if state == "failed":
            fail(f"scene {scene_id} failed to solve")
        time.sleep(1)
    fail(f"scene {scene_id} not solved after {limit_s} s")


def is_png(path):
    with open(path, "rb") as f:
        return f.read(8) == b"\x89PNG\r\n\x1a\n"


def main():
    binary = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else
                             os.path.join(ROOT, "target", "release", "volrad"))
    if not os.access(binary, os.X_OK):
        fail(f"{binary}: no volrad binary there (cargo build --release --bin volrad)")
    blocks = shell_blocks(open(os.path.join(ROOT, "README.md"), encoding="utf-8").read())
    commands = [[command_of(l) for l in b if command_of(l)] for b in blocks]
    guide = next((b for b in commands if "volrad" in b), None)
    serve = next((b for b in commands if any(c.startswith("volrad serve") for c in b)), None)
    if guide is None or serve is None:
        fail("README.md has no guide block (opening with `volrad`) or no `volrad serve` block")
    curls = commands[commands.index(serve) + 1]
    if not curls or not all(c.startswith("curl ") for c in curls):
        fail("the block after `volrad serve` should be the service's curl examples")

    work = tempfile.mkdtemp(prefix="volrad-readme-")
    copy_checkout(work)
    env = dict(os.environ, PATH=os.path.dirname(binary) + os.pathsep + os.environ["PATH"])
    if os.path.basename(binary) != "volrad":
        fail(f"{binary}: the guide calls `volrad`; give the binary of that name")

    scene_hash = None
    for command in guide:
        if command.split()[0] == "volrad":
            if command.startswith("volrad validate") and "--quick" not in command:
                command += " --quick"
            out, err = run(command, work, env)
            if command.startswith("volrad solve data/cloud.toml"):
                found = re.search(r"scene hash ([0-9a-f]{32})", out + err)
                scene_hash = found and found.group(1)
    if scene_hash is None:
        fail("`volrad solve data/cloud.toml …` did not print its scene hash")
    promised = ["volrad-default.png", "cloud.volrad", "front.png", "orbit/front_000.png",
                "orbit/front_035.png", "close.exr", "fluence.nrrd", "truth.pfm",
                "bench", "docs/validation/report.md", "v/report.md"]
    for path in promised:
        full = os.path.join(work, path)
        present = os.path.isdir(full) and os.listdir(full) or (
            os.path.isfile(full) and os.path.getsize(full) > 0)
        if not present:
            fail(f"the guide promised {path}; it is missing or empty")
    if not any(f.endswith(".csv") for f in os.listdir(os.path.join(work, "bench"))):
        fail("bench albedo wrote no CSV into bench/")
    if not os.listdir(os.path.join(work, "out")):
        fail("`volrad render data/cloud.toml -o out/` left out/ empty")

    serve_line = next(c for c in serve if c.startswith("volrad serve"))
    server = subprocess.Popen(["bash", "-c", "exec " + serve_line.rstrip("& ")], cwd=work, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        start = time.time()
        while True:
            try:
                status, page = get("/")
                if status == 200 and b"<html" in page.lower():
                    break
            except OSError:
                pass
            if server.poll() is not None:
                fail(f"`{serve_line}` exited {server.returncode}: {server.stderr.read()[-2000:]}")
            if time.time() - start > 120:
                fail(f"`{serve_line}`: no viewer page at http://{ADDR}/ after 120 s")
            time.sleep(0.5)
        print(f"ok {time.time() - start:6.1f} s  {serve_line} (the viewer page answers)")

        # The sky scene the relight example needs.
        request = urllib.request.Request(
            f"http://{ADDR}/v1/scenes?name=sky",
            data=open(os.path.join(work, "data", "cloud-sky.toml"), "rb").read(), method="POST")
        with urllib.request.urlopen(request, timeout=30) as r:
            sky = json.loads(r.read())["id"]
        cloud = None
        for command in curls:
            command = command.replace("curl -s ", "curl -s --fail ", 1)
            if cloud is None and "POST" in command and "/v1/scenes" in command:
                cloud = json.loads(run(command, work, env)[0])["id"]
                # The README: "the id is the scene hash `volrad solve` prints".
                if cloud != scene_hash:
                    fail(f"the service's id {cloud} is not the scene hash {scene_hash} that "
                         "`volrad solve data/cloud.toml` printed")
                wait_done(cloud)
                wait_done(sky)
                continue
            if cloud is None:
                fail("the curl block should open by posting a scene")
            run(command.replace("3df3…", cloud).replace("6f0e…", sky), work, env)
        for image in ["view.png", "top.png", "slice.png"]:
            if not is_png(os.path.join(work, image)):
                fail(f"{image} is not a PNG")
    finally:
        server.terminate()
        server.wait(timeout=30)
    shutil.rmtree(work, ignore_errors=True)
    print("readme_guide: every command of the README's guide and service blocks ran")


if __name__ == "__main__":
    main()
