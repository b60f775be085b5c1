"""A private one-machine Slurm cluster for the srun tests (docs/mpi.md "Slurm"): munged,
slurmctld and slurmd from Debian's packages, started in the foreground in a folder of their own,
on free ports, and stopped with the test (each also dies with the test's process). Needs root:
slurmd starts tasks as the user that submits them.

    with LocalSlurm(folder) as env:
        subprocess.run(["srun", "--mpi=pmix", "-n", "2", ...], env=env)

By default the node has the CPUs slurmd finds and binds each task to the CPUs it was given
(task/affinity), as a cluster does; LocalSlurm(folder, cpus=N) claims N CPUs instead, without
binding, so that more tasks than cores can run.
"""
import ctypes
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import time

PROGRAMS = ("munged", "slurmctld", "slurmd", "srun", "sinfo", "squeue", "scancel")


def missing_programs():
    return [p for p in PROGRAMS if not shutil.which(p)]


def free_ports(n):
    """@a n distinct ports free now, below Linux's ephemeral range (32768 and up), so that no
    outgoing connection takes one before the daemons bind it."""
    ports = []
    while len(ports) < n:
        port = random.randint(20000, 32767)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        if port not in ports:
            ports.append(port)
    return ports


def found_cpus():
    """The CPUs slurmd finds on this machine (`slurmd -C`)."""
    line = subprocess.run(["slurmd", "-C"], capture_output=True, text=True, check=True).stdout
    return int(re.search(r"\bCPUs=(\d+)", line).group(1))


def die_with_parent():
    """In the child before exec: SIGTERM when the test's process ends, however it ends."""
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class LocalSlurm:
    def __init__(self, folder, cpus=None):
        self.folder, self.daemons = os.path.abspath(folder), []
        self.binds = cpus is None
        self.cpus = found_cpus() if self.binds else cpus

    def __enter__(self):
        # A port taken between the check and a daemon's bind (another cluster's, a test's): again.
        for attempt in range(3):
            try:
                return self.start_cluster()
            except RuntimeError as e:
                if "Address already in use" not in str(e) or attempt == 2:
                    raise

    def start_cluster(self):
        d = self.folder
        if os.path.exists(d):
            shutil.rmtree(d)
        for sub in ("munge", "state", "spool"):
            os.makedirs(os.path.join(d, sub))
        os.chmod(os.path.join(d, "munge"), 0o700)
        key = os.path.join(d, "munge", "key")
        with open(key, "wb") as f:
            f.write(os.urandom(1024))
        os.chmod(key, 0o400)
        sock = os.path.join(d, "munge", "sock")
        host = socket.gethostname().split(".")[0]
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2 ** 21  # half, in MiB
        conf = os.path.join(d, "slurm.conf")
        ports = free_ports(2)
        # CPUs as asked, not only as found (config_overrides), so that -n 4 can run on 2 cores.
        # Job ids start at a random number: the PMIx plugin names its folders in /tmp by job id.
        with open(conf, "w") as f:
            f.write(f"""ClusterName=isouqtest
SlurmctldHost={host}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={sock}
CredType=cred/munge
SlurmctldPort={ports[0]}
SlurmdPort={ports[1]}
StateSaveLocation={d}/state
SlurmdSpoolDir={d}/spool
SlurmctldPidFile={d}/slurmctld.pid
SlurmdPidFile={d}/slurmd.pid
SlurmctldLogFile={d}/slurmctld.log
SlurmdLogFile={d}/slurmd.log
SlurmdParameters=config_overrides
ProctrackType=proctrack/pgid
TaskPlugin=task/{"affinity" if self.binds else "none"}
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
FirstJobId={random.randint(10, 10 ** 6)}
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName={host} NodeAddr=127.0.0.1 CPUs={self.cpus} RealMemory={memory} State=UNKNOWN
PartitionName=local Nodes=ALL Default=YES MaxTime=INFINITE State=UP
""")
        self.env = dict(os.environ, SLURM_CONF=conf)
        try:
            self.start(["munged", "-F", "-f", f"--socket={sock}", f"--key-file={key}",
                        f"--log-file={d}/munge/log", f"--pid-file={d}/munge/pid", f"--seed-file={d}/munge/seed"])
            self.wait(lambda: os.path.exists(sock), "munged")
            self.start(["slurmctld", "-D", "-f", conf])
            self.start(["slurmd", "-D", "-f", conf])
            self.wait(lambda: subprocess.run(["sinfo", "-h", "-o", "%t"], env=self.env, capture_output=True,
                                             text=True).stdout.strip() == "idle", "the node")
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self.env

    def start(self, cmd):
        log = open(os.path.join(self.folder, cmd[0] + ".out"), "w")
        self.daemons.append(subprocess.Popen(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                             preexec_fn=die_with_parent))

    def wait(self, ready, what):
        deadline = time.time() + 60
        while not ready():
            dead = [p.args[0] for p in self.daemons if p.poll() is not None]
            if dead or time.time() > deadline:
                logs = {n: open(os.path.join(self.folder, n)).read()[-2000:]
                        for n in os.listdir(self.folder) if n.endswith((".log", ".out"))}
                raise RuntimeError(f"Slurm: {what} not ready ({'stopped: ' + ', '.join(dead) if dead else 'timeout'}): {logs}")
            time.sleep(0.2)

    def __exit__(self, *exc):
        for p in reversed(self.daemons):
            p.terminate()
        for p in reversed(self.daemons):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.daemons = []
        return False
