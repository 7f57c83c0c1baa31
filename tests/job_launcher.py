"""`python script.py` for a Snakemake job in the tests, run by the job server
(`forked_jobs.py`): started as `python -S -I job_launcher.py script.py`, it imports nothing but
the standard library's few modules, sends its arguments, folder, environment and standard
streams to the server, and leaves with the script's exit status. Where the server answers
`exec` (the job's environment differs in what an interpreter reads as it starts), it becomes
`python script.py` itself."""

import json
import os
import signal
import socket
import sys

conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
conn.connect(os.environ["MJTRIAL_TEST_JOB_SERVER"])
body = json.dumps({"argv": sys.argv[1:], "cwd": os.getcwd(), "env": dict(os.environ)}).encode()
socket.send_fds(conn, [len(body).to_bytes(8, "big")], [0, 1, 2])
conn.sendall(body)
reply = b""
while chunk := conn.recv(64):
    reply += chunk
if reply == b"exec\n":
    conn.close()
    os.execv(sys.executable, [sys.executable, *sys.argv[1:]])
if not reply:
    sys.exit("job_launcher: the job server answered nothing")
code = int(reply)
if code < 0:  # the script's process was killed by a signal: so is this one
    signal.signal(-code, signal.SIG_DFL)
    os.kill(os.getpid(), -code)
sys.exit(code)
