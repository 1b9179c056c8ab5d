"""``splat4d sample NAME OUT``: placeholder until samples land."""
HELP = "render a procedural animated test object to a dataset (D-NeRF layout)"


def add_args(p):
    p.add_argument("name", nargs="?")
    p.add_argument("out", nargs="?")


def run(args):
    return 0
