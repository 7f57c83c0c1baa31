#!/usr/bin/env bash
# The SLURM round trip: a one-node SLURM cluster on this machine, the workflow run on it through
# profiles/slurm on a small N, and its results compared with a local run's.
#
# Needs root on Debian (installs slurmctld, slurmd, slurm-client and munge from Debian's
# archive if missing) and the optional extra `pip install -e '.[slurm]'` in the active Python
# environment. Everything it writes goes to a temporary folder, except munge's socket under
# /run/munge and /etc/slurm/slurm.conf, which it removes on exit: the job step's `srun` reads
# the config from there (the jobstep plugin drops SLURM_CONF from its environment), and a
# slurm.conf left behind with no controller answering would make every later `snakemake` call
# wait ~9 s while the SLURM plugin's import runs `scontrol show config`. It refuses to run
# where a slurm.conf it did not write exists (a real SLURM installation). Every daemon it
# starts is stopped on exit, failure or interrupt included. Ends with one line: PASS or FAIL.
#
# Then the same, alongside, for a small benchmark (config/benchmark.yaml, its cart-pole task
# alone: 8 states, 3 seeds).
#
# Environment: MJTRIAL_SLURM_N (states, default 12), MJTRIAL_SLURM_BENCHMARK=0 skips the
# benchmark, MJTRIAL_SLURM_BENCHMARK_N (its states, default 8),
# MJTRIAL_SLURM_TIMEOUT (seconds allowed to each Snakemake run, default 600),
# MJTRIAL_SLURM_KEEP=1 keeps the temporary folder.
set -euo pipefail

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
n_states=${MJTRIAL_SLURM_N:-12}
bench_n=${MJTRIAL_SLURM_BENCHMARK_N:-8}
run_timeout=${MJTRIAL_SLURM_TIMEOUT:-600}
partition=mjtrial
# Not SLURM's default ports (6817, 6818).
ctld_port=16817
slurmd_port=16818
slurm_conf=/etc/slurm/slurm.conf
# The first line of the slurm.conf this script writes, so that it only ever removes its own.
conf_marker="# mjtrial SLURM round trip (tests/cluster/run_slurm_test.sh): removed on exit"
wrote_conf=false

start_time=$SECONDS
passed=false
work=""
declare -A run_pid=()  # the Snakemake runs while they run: "experiment-slurm" -> pid, ...
stop_pidfiles=()  # daemons this script started, in start order

say() { echo "slurm-test: $*"; }

stop_daemon() {  # pid file: SIGTERM, up to 15 s to exit, then SIGKILL
    local pid
    [[ -s $1 ]] || return 0
    pid=$(cat "$1")
    kill "$pid" 2>/dev/null || return 0
    for _ in $(seq 30); do
        kill -0 "$pid" 2>/dev/null || return 0
        sleep 0.5
    done
    kill -9 "$pid" 2>/dev/null || true
}

show_logs() {  # the tails that say why a run failed
    local log
    for log in "$work"/*.log "$work"/*-slurm/.snakemake/slurm_logs/*/*.log \
        "$work"/*-slurm/.snakemake/slurm_logs/*/*/*.log; do
        [[ -s $log ]] || continue
        echo "----- ${log#"$work"/} (last 40 lines)"
        tail -n 40 "$log"
    done
}

cleanup() {
    local status=$?
    set +e
    trap - EXIT INT TERM
    local pid
    for pid in "${run_pid[@]}"; do  # timeout passes the signal on to Snakemake
        kill "$pid" 2>/dev/null
        wait "$pid" 2>/dev/null
    done
    if [[ $passed != true && -n $work ]]; then
        show_logs
    fi
    if [[ -n $work && -s $work/slurmctld.pid ]]; then
        # Cancel whatever is still queued or running, and give the job steps time to end.
        squeue -h -o %i 2>/dev/null | xargs -r scancel 2>/dev/null
        for _ in $(seq 20); do
            [[ -z $(squeue -h -o %i 2>/dev/null) ]] && break
            sleep 0.5
        done
    fi
    local i
    for ((i = ${#stop_pidfiles[@]} - 1; i >= 0; i--)); do
        stop_daemon "${stop_pidfiles[i]}"
    done
    if [[ $wrote_conf == true ]]; then
        rm -f "$slurm_conf"
    fi
    if [[ -n $work && ${MJTRIAL_SLURM_KEEP:-0} != 1 ]]; then
        rm -rf "$work"
    elif [[ -n $work ]]; then
        say "kept $work"
    fi
    local elapsed=$((SECONDS - start_time))
    if [[ $passed == true ]]; then
        echo "PASS: SLURM round trip (N = $n_states): results equal a local run's (${elapsed} s)"
        exit 0
    fi
    echo "FAIL: SLURM round trip (N = $n_states) after ${elapsed} s (exit status $status)"
    exit $((status == 0 ? 1 : status))
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

fail() {
    say "$*"
    exit 1
}

[[ $(id -u) == 0 ]] || fail "needs root (it installs and starts SLURM's daemons)"
command -v snakemake >/dev/null || fail "no snakemake on PATH: activate the project's environment"
python -c "import snakemake_executor_plugin_slurm" 2>/dev/null ||
    fail "the SLURM executor plugin is missing: pip install -e '.[slurm]'"

# --- SLURM and munge from Debian's archive, if missing
missing=()
for pair in slurmctld:slurmctld slurmd:slurmd sbatch:slurm-client munged:munge; do
    command -v "${pair%%:*}" >/dev/null || missing+=("${pair#*:}")
done
if ((${#missing[@]})); then
    say "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

work=$(mktemp -d -t mjtrial-slurm.XXXXXX)
chmod 755 "$work"
# Nothing may write to the real home folder (rerun writes analytics settings there).
export HOME="$work/home" XDG_CONFIG_HOME="$work/home/.config" XDG_CACHE_HOME="$work/home/.cache" \
    XDG_DATA_HOME="$work/home/.local/share" RERUN_ANALYTICS=0 MPLBACKEND=Agg
mkdir -p "$HOME"

# --- munge: SLURM's daemons and clients authenticate through it
if munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
    say "munged already running; using it"
else
    if [[ ! -s /etc/munge/munge.key ]]; then
        install -d -o munge -g munge -m 0700 /etc/munge
        dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
        chown munge:munge /etc/munge/munge.key
        chmod 0400 /etc/munge/munge.key
    fi
    install -d -o munge -g munge -m 0755 /run/munge
    install -d -o munge -g munge -m 0700 /var/lib/munge /var/log/munge
    runuser -u munge -- munged --pid-file=/run/munge/munged.pid
    stop_pidfiles+=(/run/munge/munged.pid)
    for _ in $(seq 20); do
        munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break
        sleep 0.25
    done
    munge -n | unmunge >/dev/null || fail "munged does not answer"
fi

# --- a one-node cluster: this host, its CPUs and memory as slurmd measures them
node=$(hostname -s)
hardware=$(slurmd -C | head -1)
cpus=$(sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' <<<"$hardware")
memory=$(sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' <<<"$hardware")
mkdir -p "$work/state" "$work/spool"
if [[ -e $slurm_conf && $(head -1 "$slurm_conf") != "$conf_marker" ]]; then
    fail "$slurm_conf exists and was not written by this script: not touching a real SLURM"
fi
mkdir -p "$(dirname "$slurm_conf")"
wrote_conf=true
cat >"$slurm_conf" <<EOF
$conf_marker
ClusterName=mjtrial-test
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd.log
# No cgroups in a container: process groups track a job, and no task plugin binds it.
ProctrackType=proctrack/pgid
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
SchedulerType=sched/backfill
# No accounting database (slurmdbd): sacct fails, the profile polls with squeue.
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MpiDefault=none
MailProg=/bin/true
ReturnToService=2
KillWait=5
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$memory State=UNKNOWN
PartitionName=$partition Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
say "node $node: $cpus CPUs, $memory MB; config $slurm_conf"

slurmctld -i
stop_pidfiles+=("$work/slurmctld.pid")
slurmd -N "$node"
stop_pidfiles+=("$work/slurmd.pid")
state=""
for _ in $(seq 60); do
    state=$(sinfo -h -N -n "$node" -o %t 2>/dev/null || true)
    [[ $state == idle ]] && break
    sleep 1
done
[[ $state == idle ]] || fail "node $node is '$state', not idle, after 60 s"
say "cluster up after $((SECONDS - start_time)) s"

# --- the same small experiment on SLURM and locally, in two copies of the workflow
# Each run in a copy of the workflow of its own: NAME-slurm and NAME-local. Its config file lives
# inside the copy (config/small.yaml): the workflow refuses one outside its folder, since a run's
# source/, crate and zip name files relative to it.
for copy in {experiment,benchmark}-{slurm,local}; do
    mkdir -p "$work/$copy"
    cp -r "$repo"/{Snakefile,workflow,config,models,tasks,profiles,policies} "$work/$copy/"
done
for copy in experiment-slurm experiment-local; do
    cat >"$work/$copy/config/small.yaml" <<EOF
states:
  n: $n_states
analysis:
  n_resamples: 500
  first_k: $((n_states < 10 ? n_states : 10))
EOF
done

# start_runs NAME CONFIGFILE...: the workflow on SLURM (--workflow-profile profiles/slurm) in
# NAME-slurm and locally (-c2) in NAME-local, in the background, logs snakemake-NAME-slurm.log
# and snakemake-NAME-local.log. The experiment's and the benchmark's runs go side by side
# (the results do not depend on how busy the machine is): the node's CPUs are its slots, and
# each run alone leaves one idle at times (225 s together, 343 s one after the other).
declare -A run_start=()
start_runs() {
    local name=$1
    shift
    (cd "$work/$name-local" && exec timeout "$run_timeout" snakemake -c2 --configfile "$@" \
        </dev/null >"$work/snakemake-$name-local.log" 2>&1) &
    run_pid[$name-local]=$!
    (cd "$work/$name-slurm" && exec timeout "$run_timeout" snakemake --workflow-profile \
        profiles/slurm --configfile "$@" </dev/null >"$work/snakemake-$name-slurm.log" 2>&1) &
    run_pid[$name-slurm]=$!
    run_start[$name]=$SECONDS
}

# finish_runs NAME: wait for NAME's two runs (`wait`, unlike a command in the foreground, lets
# an interrupt reach the trap at once); fail if either failed.
finish_runs() {
    local name=$1 where status jobs
    for where in slurm local; do
        status=0
        wait "${run_pid[$name-$where]}" || status=$?
        unset "run_pid[$name-$where]"
        ((status == 0)) ||
            fail "the $name run ($where) failed, status $status (snakemake-$name-$where.log)"
    done
    jobs=$(grep -c 'has been submitted with SLURM jobid' "$work/snakemake-$name-slurm.log" ||
        true)
    say "$name: both runs done after $((SECONDS - run_start[$name])) s, $jobs SLURM job(s)"
}

# --- a small benchmark in its copies: the closed-loop cart-pole alone (the gantry's open-loop
# rollouts run on SLURM in the experiment; each task adds 15 SLURM jobs, 2 minutes here), its N
# from its experiment config
benchmark=${MJTRIAL_SLURM_BENCHMARK:-1}
if [[ $benchmark == 1 ]]; then
    for copy in benchmark-slurm benchmark-local; do
        python - "$work/$copy/config" "$bench_n" <<'SMALL'
import sys
from pathlib import Path

import yaml

folder, n = Path(sys.argv[1]), int(sys.argv[2])
config = yaml.safe_load((folder / "cartpole_latency.yaml").read_text())
config["states"]["n"] = n
config["analysis"]["first_k"] = min(config["analysis"]["first_k"], n)
(folder / "cartpole_latency.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
bench = yaml.safe_load((folder / "benchmark.yaml").read_text())
del bench["benchmark"]["tasks"]["gantry_lift"]
for method in bench["benchmark"]["methods"].values():
    del method["tasks"]["gantry_lift"]
# the MLP's checkpoints of the 3 seeds below (small_benchmark.yaml): one file per seed
mlp = bench["benchmark"]["methods"]["mlp_es"]["tasks"]["cartpole_latency"]
mlp["policy"] = mlp["policy"].replace("seed-*", "seed-[1-3]")
(folder / "benchmark.yaml").write_text(yaml.safe_dump(bench, sort_keys=False))
SMALL
    done
    for copy in benchmark-slurm benchmark-local; do
        cat >"$work/$copy/config/small_benchmark.yaml" <<YAML
benchmark:
  seeds: [1, 2, 3]
  result: development
  methods:
    tuned: {budget: 48, episodes_per_candidate: 4}
  analysis: {n_resamples: 200}
  closest_calls: 2
YAML
    done
fi

say "running the experiment on SLURM (--workflow-profile profiles/slurm) and locally (-c2)"
start_runs experiment config/small.yaml
if [[ $benchmark == 1 ]]; then
    # states, training, evaluation, solvability, closest calls and report as SLURM jobs
    say "running a benchmark (the cart-pole, $bench_n states, 3 seeds) on SLURM and locally, alongside"
    start_runs benchmark config/benchmark.yaml config/small_benchmark.yaml
fi

finish_runs experiment
results=$(python -c 'import sys; from mjtrial.files.layout import Layout; print(Layout.of(sys.argv[1]).root)' \
    "$(python -c 'import sys, yaml; print(yaml.safe_load(open(sys.argv[1]))["experiment"])' \
        "$work/experiment-local/config/config.yaml")")
python "$repo/tests/cluster/compare_results.py" "$work/experiment-slurm/$results" \
    "$work/experiment-local/$results" ||
    fail "the SLURM run's results differ from the local run's"

if [[ $benchmark == 1 ]]; then
    finish_runs benchmark
    python "$repo/tests/cluster/compare_results.py" "$work/benchmark-slurm/results/benchmark" \
        "$work/benchmark-local/results/benchmark" ||
        fail "the benchmark's results on SLURM differ from the local run's"
fi
passed=true
