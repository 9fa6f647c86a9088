"""The one native part: enip_farm/server/_mmsg.c (batched UDP for the cyclic I/O thread). Optional:
where no compiler exists the build goes on without it and server/batch.py uses recvfrom/sendto."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("enip_farm.server._mmsg", ["enip_farm/server/_mmsg.c"], optional=True,
                             extra_compile_args=["-O2", "-Wall"])])
