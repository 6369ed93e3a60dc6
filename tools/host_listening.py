"""Wait until a storetrack-host process listens on its UDP port, for the integration tests that
feed it.

The host binds its UDP socket after loading its files and building its processing chain. A
datagram sent before is lost, so a test that counts what arrives must not start on a fixed
sleep: on a loaded machine the start takes longer (the test point once lost 11 datagrams that
way). The bound port is read from the kernel's socket table (/proc/net/udp, udp6), whatever the
host's log level."""
import time


def udp_port_bound(port):
    """True when some socket of this network namespace is bound to UDP `port`."""
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table, encoding="ascii") as f:
                next(f)  # header
                for line in f:
                    local = line.split()[1]  # address:port, hex
                    if int(local.rsplit(":", 1)[1], 16) == port:
                        return True
        except FileNotFoundError:
            continue
    return False


def wait_until_listening(process, port, log_path, timeout_s=60.0):
    """Returns once UDP `port` is bound; raises RuntimeError, with the host's log tail, if the
    process ends first or the timeout passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if udp_port_bound(port):
            return
        if process.poll() is not None:
            break
        time.sleep(0.05)
    try:
        with open(log_path, encoding="utf-8", errors="replace") as f:
            tail = f.read()[-2000:]
    except FileNotFoundError:
        tail = "(no log)"
    state = ("exited with %s" % process.returncode if process.poll() is not None
             else "not bound to UDP port %d after %.0f s" % (port, timeout_s))
    raise RuntimeError("storetrack-host %s; log %s:\n%s" % (state, log_path, tail))
