"""Stand-in: the `Run` type the authors' rollouts module names in an annotation."""


class Run:
    pass
