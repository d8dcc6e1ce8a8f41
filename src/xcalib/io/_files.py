"""The former name of :mod:`xcalib.io.files` (the public file toolkit), kept so that older imports
(``from xcalib.io._files import atomic_write``) still work: it *is* that module (one module
object, so a patch of one patches the other). New code imports :mod:`xcalib.io.files`."""

import sys

from . import files as _files

sys.modules[__name__] = _files
