"""Import an upstream checkout's model code without its training-only dependencies.

``install(["wandb", ...])`` makes every module under those top-level names importable as an
empty stand-in whose attributes are inert callables (logging, video writing, data loading and
training libraries the encoders' packages import but their forward pass never calls).
"""

import sys, types, importlib.abc, importlib.machinery

class _Dummy:
    def __init__(self, *a, **k): pass
    def __call__(self, *a, **k): return _Dummy()
    def __getattr__(self, name): return _Dummy()
    def __mro_entries__(self, bases): return (object,)

class _StubModule(types.ModuleType):
    __path__ = []
    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return _Dummy()

class StubFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def __init__(self, roots): self.roots = set(roots)
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in self.roots:
            return importlib.machinery.ModuleSpec(name, self, is_package=True)
    def create_module(self, spec): return _StubModule(spec.name)
    def exec_module(self, module): pass

def install(roots):
    """Put the stand-ins first on the import path; returns a function that takes them off."""
    finder = StubFinder(roots)
    sys.meta_path.insert(0, finder)

    def uninstall():
        sys.meta_path.remove(finder)
        for name in [m for m in sys.modules if m.split(".")[0] in finder.roots]:
            if isinstance(sys.modules[name], _StubModule):
                del sys.modules[name]
    return uninstall
