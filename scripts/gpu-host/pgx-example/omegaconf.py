"""Stand-in for omegaconf's CLI parsing (key=value arguments) on a host without a package index."""
import sys


class OmegaConf:
    @staticmethod
    def from_cli():
        out = {}
        for arg in sys.argv[1:]:
            k, v = arg.split("=", 1)
            for cast in (int, float):
                try:
                    v = cast(v)
                    break
                except ValueError:
                    pass
            if v in ("true", "false", "True", "False"):
                v = v.lower() == "true"
            out[k] = v
        return out
    @staticmethod
    def to_object(x):
        return x
