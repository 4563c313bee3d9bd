"""Two one-CPU Ray nodes on this machine, standing in for two machines, held by a process of
their own: `python ray_nodes.py` prints the head's address on its first line, keeps both nodes
up while its standard input is open and shuts them down when it closes.

Why a process of its own: Ray started, stopped and restarted inside the pytest process leaves
its core worker's threads behind, and pytest then segfaulted at exit in CI after every test had
passed (Ray's own issue 31145: restarting Ray in one process with its background threads
running). The tests run `python -m dribble_models.cluster` as a child too, so the pytest process
never connects to Ray at all."""

import sys

from ray.cluster_utils import Cluster


def main() -> int:
    nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        nodes.add_node(num_cpus=1)
        nodes.wait_for_nodes()
        print(nodes.address, flush=True)
        sys.stdin.read()  # until the test closes the pipe (or dies)
    finally:
        nodes.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
