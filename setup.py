"""Build of shipstar's compiled kernels (plain C, Python's buffer protocol, no NumPy headers).

Everything else about the package is in ``pyproject.toml``.  The kernels are C99 compiled
by the C compiler that builds Python's own extensions (gcc here), at install time from the
sources in the package: nothing is downloaded and nothing is compiled at run time.
"""

from setuptools import Extension, setup

_CFLAGS = ["-O3", "-std=c99", "-fno-math-errno", "-Wall"]

#: QUEST in C, included by the identification and attitude kernels
_QUEST_H = ["src/shipstar/_cquest.h"]

EXTENSIONS = [
    Extension("shipstar._cfits", ["src/shipstar/_cfits.c"], extra_compile_args=_CFLAGS),
    Extension("shipstar.extract._ckernels", ["src/shipstar/extract/_ckernels.c"], extra_compile_args=_CFLAGS),
    Extension("shipstar.identify._ckernels", ["src/shipstar/identify/_ckernels.c"], extra_compile_args=_CFLAGS,
              depends=_QUEST_H),
    Extension("shipstar.attitude._ckernels", ["src/shipstar/attitude/_ckernels.c"], extra_compile_args=_CFLAGS,
              depends=_QUEST_H),
]

setup(ext_modules=EXTENSIONS)
