# Runs `isouq mesh` (SPEC §8) in a subprocess: finds the binary, builds the command line, polls
# progress, cancels. No bpy, so the operator (modal timer) and the tests share it. A frame
# sequence (SPEC §10: an input with ####) runs as one `isouq mesh` over every frame
# (SequenceJob), writing its frames into a folder that stays.

import json
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
from dataclasses import dataclass, field

ENV_BINARY = "ISOUQ_CLI"
_PERCENT = re.compile(rb"(\d{1,3}(?:\.\d+)?)\s*%")
_FRAMES_DONE = re.compile(rb"frame\s+(\d+)\s*(?:/|of)\s*(\d+)", re.IGNORECASE)
_FRAME_WRITTEN = re.compile(rb"^frame -?\d+: (?:wrote|kept) ", re.MULTILINE)


def spawn(cmd, stdout_path, stderr_path):
    """Starts `cmd` with stdout to a file and stderr on a pseudo-terminal whose output a thread
    copies to `stderr_path`: the CLI draws its progress bar only on a terminal. Without a pty
    (not POSIX), stderr goes to the file directly. Returns (process, drain thread or None)."""
    out = open(stdout_path, "wb")
    try:
        try:
            import pty
            master, slave = pty.openpty()
        except (ImportError, OSError):
            with open(stderr_path, "wb") as err:
                return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=err), None
        try:
            process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=slave)
        except BaseException:
            os.close(master)
            raise
        finally:
            os.close(slave)
    finally:
        out.close()
    thread = threading.Thread(target=_drain, args=(master, stderr_path), daemon=True)
    thread.start()
    return process, thread


def _drain(fd, path):
    """Copies what the pty gives into `path` until the child closes it (EIO on Linux)."""
    with open(path, "wb") as f:
        while True:
            try:
                data = os.read(fd, 65536)
            except OSError:
                break
            if not data:
                break
            f.write(data)
            f.flush()
    os.close(fd)
_T_COLUMN = re.compile(r"^t_(\w+)$")
_READ_ERRORS = (OSError, RuntimeError, KeyError, TypeError, ValueError, subprocess.TimeoutExpired)


def nodes_document(binary):
    """`isouq nodes --json` (format "isouq-nodes", version 1): node declarations and the column
    and method tables, the one source of names that the CLI and graphs also use."""
    done = subprocess.run([binary, "nodes", "--json"], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        raise RuntimeError(f"'{binary} nodes --json' failed: {done.stderr.strip() or done.returncode}")
    doc = json.loads(done.stdout)
    if doc.get("format") != "isouq-nodes" or doc.get("format_version") != 1:
        raise RuntimeError(f"'{binary} nodes --json' is not isouq-nodes version 1")
    return doc


def node_specs(binary):
    """The node declarations of `isouq nodes --json` by type: parameter names, menus, tooltips."""
    return {node["type"]: node for node in nodes_document(binary)["nodes"]}


def parm_spec(specs, node_type, token):
    """One parameter's declaration (token, label, type, default, ranges, menu, tooltip)."""
    for parm in specs[node_type]["parms"]:
        if parm["token"] == token:
            return parm
    raise KeyError(f"node '{node_type}' has no parameter '{token}'")


def method_menu(binary):
    """The `mesh` node's method tokens as the binary declares them, or None when the binary
    cannot say (an older build): then the CLI itself rejects an unknown method."""
    try:
        return parm_spec(node_specs(binary), "mesh", "method")["menu"]
    except _READ_ERRORS:
        return None


@dataclass(frozen=True)
class Vocabulary:
    """Mesh column names and method tokens (SPEC §6, §10): `columns` holds {name, type, element,
    description, measure, summary} (the add-on reads name, description, measure and summary),
    `methods` {token, label, column}, both in table order."""
    columns: tuple
    methods: tuple

    def measures(self):
        """Vertex columns to threshold or heat-map."""
        return [c["name"] for c in self.columns if c["measure"]]

    def summarised(self):
        """Vertex columns whose {min, max, mean, rms} the summary reports."""
        return [c["name"] for c in self.columns if c["summary"]]

    def description(self, name):
        return next((c["description"] for c in self.columns if c["name"] == name), "")

    def method_columns(self):
        """{method token: its t column}."""
        return {m["token"]: m["column"] for m in self.methods}


_vocabularies = {}


def vocabulary(binary):
    """The `columns` and `methods` tables of `binary nodes --json`, read once per build of the
    binary (path and modification time). None without a binary or from one that lacks them."""
    try:
        key = (binary, os.stat(binary).st_mtime_ns)
    except (OSError, TypeError):
        return None
    if key not in _vocabularies:
        try:
            doc = nodes_document(binary)
            _vocabularies[key] = Vocabulary(tuple(doc["columns"]), tuple(doc["methods"]))
        except _READ_ERRORS:
            _vocabularies[key] = None
    return _vocabularies[key]


def mesh_vocabulary(vertex_columns):
    """What a mesh's own vertex columns (name -> numpy type string, e.g. "<f4") tell when no
    binary can: a method per t_<name> column (token <name>), and every other float column is a
    measure that the summary panel lists."""
    columns, methods = [], []
    for name, dtype in vertex_columns.items():
        method = _T_COLUMN.match(name)
        if method:
            methods.append({"token": method.group(1), "label": method.group(1), "column": name})
        number = dtype.lstrip("<>=|")[:1] == "f" and not method
        columns.append({"name": name, "description": "", "measure": number, "summary": number})
    return Vocabulary(tuple(columns), tuple(methods))


def repo_binaries():
    """Build-tree candidates next to this add-on's source (works through an install symlink)."""
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__))))
    try:
        builds = sorted(d for d in os.listdir(repo) if d.startswith("build"))
    except OSError:
        return []
    return [os.path.join(repo, d, "houdini_style_nodes", "isouq") for d in builds]


def find_binary(preference=""):
    """The isouq binary: the add-on preference, else $ISOUQ_CLI, else `isouq` on PATH, else the
    repo's build directories. Returns (path or None, description of what was tried)."""
    if preference:
        path = os.path.expanduser(preference)
        found = shutil.which(path) if os.sep not in path else path
        ok = found and os.path.isfile(found) and os.access(found, os.X_OK)
        return (found if ok else None), f"preference '{preference}'"
    env = os.environ.get(ENV_BINARY)
    if env:
        ok = os.path.isfile(env) and os.access(env, os.X_OK)
        return (env if ok else None), f"${ENV_BINARY}='{env}'"
    on_path = shutil.which("isouq")
    if on_path:
        return on_path, "PATH"
    for candidate in repo_binaries():
        if os.path.isfile(candidate) and os.access(candidate, os.X_OK):
            return candidate, "repo build directory"
    return None, "PATH and the repo's build*/houdini_style_nodes/isouq"


def is_generated(path):
    """A `field:NAME` or `formula:EXPR` input (SPEC §8): computed by the CLI, not a file."""
    return path.startswith(("field:", "formula:"))


def input_name(path):
    """Object name for an input: the file's stem, or the field's name."""
    if path.startswith("field:"):
        return path[len("field:"):]
    if path.startswith("formula:"):
        return "formula"
    return os.path.splitext(os.path.basename(path))[0]


@dataclass
class MeshRequest:
    """Arguments of `isouq mesh INPUT -o OUT.ply ...`."""
    input: str
    isovalue: float = None
    method: str = None              # None: the CLI's default
    hidden_features: bool = False
    subdivisions: int = 4
    grid: str = ""
    threads: int = 0
    resolution: int = 0
    frames: str = ""                # sequences: --frames A-B[:STEP]; "" every frame on disk
    resume: bool = False            # sequences: --resume
    skip_missing: bool = False      # sequences: --skip-missing

    def command(self, binary, out, summary, hidden_out=None):
        cmd = [binary, "mesh", self.input, "-o", out]
        if self.method:
            cmd += ["--method", self.method]
        cmd += ["--summary", summary]
        if self.isovalue is not None:
            cmd += ["--isovalue", repr(float(self.isovalue))]
        if self.hidden_features:
            cmd += ["--hidden-features", "--subdivisions", str(self.subdivisions)]
            if hidden_out:
                cmd += ["--hidden-out", hidden_out]
        if self.grid:
            cmd += ["--grid", self.grid]
        if self.resolution > 0:
            cmd += ["--resolution", str(self.resolution)]
        if self.threads > 0:
            cmd += ["--threads", str(self.threads)]
        if self.frames:
            cmd += ["--frames", self.frames]
        if self.resume:
            cmd += ["--resume"]
        if self.skip_missing:
            cmd += ["--skip-missing"]
        return cmd


@dataclass
class Job:
    """One background run. poll() -> None while running, else the exit status."""
    request: MeshRequest
    binary: str
    workdir: str = field(default_factory=lambda: tempfile.mkdtemp(prefix="isouq_"))
    process: subprocess.Popen = None
    cancelled: bool = False

    @property
    def mesh_path(self):
        return os.path.join(self.workdir, "mesh.ply")

    @property
    def hidden_path(self):
        return os.path.join(self.workdir, "hidden.ply") if self.request.hidden_features else None

    @property
    def summary_path(self):
        return os.path.join(self.workdir, "summary.json")

    @property
    def _stderr_path(self):
        return os.path.join(self.workdir, "stderr.txt")

    @property
    def _stdout_path(self):
        return os.path.join(self.workdir, "stdout.txt")

    def start(self):
        cmd = self.request.command(self.binary, self.mesh_path, self.summary_path, self.hidden_path)
        self.process, self._drainer = spawn(cmd, self._stdout_path, self._stderr_path)
        return self

    def poll(self):
        """None while running; the exit status once the process ended and its stderr is read."""
        status = self.process.poll()
        if status is not None:
            self._join()
        return status

    def wait(self, timeout=None):
        status = self.process.wait(timeout)
        self._join()
        return status

    def _join(self):
        drain = getattr(self, "_drainer", None)
        if drain is not None:
            drain.join(5.0)

    def progress(self):
        """Last percentage the CLI's progress bar printed, in [0, 1], or None."""
        tail = self._stderr_tail(4096)
        found = _PERCENT.findall(tail)
        return min(float(found[-1]) / 100.0, 1.0) if found else None

    def frames_done(self):
        """(frames finished, frames in the run) from the CLI's "frame i/N" progress, or None."""
        found = _FRAMES_DONE.findall(self._stderr_tail(4096))
        return (int(found[-1][0]), int(found[-1][1])) if found else None

    def cancel(self, grace=3.0):
        """SIGINT (the CLI exits 130 and leaves no output), then SIGKILL after `grace` s."""
        self.cancelled = True
        if self.process and self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(grace)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process:
            self._join()

    def error_message(self):
        """The CLI's `isouq: error:` line, else the last stderr line, else the status."""
        text = self._stderr_tail(65536).decode("utf-8", errors="replace")
        lines = [l.strip() for l in text.splitlines() if l.strip()]
        for line in reversed(lines):
            if line.startswith("isouq: error:"):
                return line
        status = self.process.returncode if self.process else None
        last = lines[-1] if lines else "no message"
        return f"isouq exited with status {status}: {last}"

    def _stderr_tail(self, size):
        try:
            with open(self._stderr_path, "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - size))
                return f.read()
        except OSError:
            return b""

    def cleanup(self):
        shutil.rmtree(self.workdir, ignore_errors=True)


def _last_segment(data):
    """The last progress redraw: the text after the last carriage return or newline."""
    return re.split(rb"[\r\n]", data.rstrip(b"\r\n"))[-1] if data else b""


@dataclass
class SequenceJob(Job):
    """`isouq mesh 'in.####.vdb' -o 'DIR/NAME.####.ply' --summary DIR/NAME.json` over a frame
    sequence. The frames stay in `output_dir` (they are loaded frame by frame later); only the
    temporary folder holding stderr is removed. `total` is the number of frames expected, for
    progress before the CLI first says "frame i/N"."""
    output_dir: str = ""
    name: str = "sequence"
    total: int = 0
    _best: float = 0.0

    @property
    def mesh_path(self):
        return os.path.join(self.output_dir, f"{self.name}.####.ply")

    @property
    def hidden_path(self):
        return (os.path.join(self.output_dir, f"{self.name}_hidden.####.ply")
                if self.request.hidden_features else None)

    @property
    def summary_path(self):
        return os.path.join(self.output_dir, f"{self.name}.json")

    def start(self):
        os.makedirs(self.output_dir, exist_ok=True)
        return super().start()

    def frames_done(self):
        """(frames finished, frames in the run): from the progress bar's "frame i/N" prefix,
        else from the "frame F: wrote ..." lines the CLI prints (and flushes) on stdout after
        each frame, over `total`."""
        found = super().frames_done()
        written = self._frames_written()
        if found is None:
            return (written, self.total) if written or self.total else None
        return (max(found[0], written), found[1])

    def _frames_written(self):
        try:
            with open(self._stdout_path, "rb") as f:
                return len(_FRAME_WRITTEN.findall(f.read()))
        except OSError:
            return 0

    def progress(self):
        """Fraction of the run: (frames finished + the current frame's last percentage) over the
        frames, never going back (a frame's stages each count from 0 to 100%)."""
        done = self.frames_done()
        if done is None or done[1] <= 0:
            return None
        finished, total = done
        line = _last_segment(self._stderr_tail(4096))
        percent = _PERCENT.findall(line) if finished < total else []
        fraction = (finished + (float(percent[-1]) / 100.0 if percent else 0.0)) / total
        self._best = max(self._best, min(fraction, 1.0))
        return self._best
