"""The native parts, both optional: where no compiler exists the build goes on without them.
enip_farm/server/_mmsg.c: batched UDP for the cyclic I/O thread (server/batch.py falls back to
recvfrom/sendto); enip_farm/server/_class1*.c: the per-packet work of established class-1 connections
(server/native.py; without it the pure-Python path runs every connection), one extension of four
sources sharing _class1.h: the type and module, the state moves, O->T, T->O and supervision."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("enip_farm.server._mmsg", ["enip_farm/server/_mmsg.c"], optional=True,
                             depends=["enip_farm/server/_receive.h"],
                             extra_compile_args=["-O2", "-Wall"]),
                   Extension("enip_farm.server._class1",
                             ["enip_farm/server/_class1.c", "enip_farm/server/_class1_state.c",
                              "enip_farm/server/_class1_o_t.c", "enip_farm/server/_class1_t_o.c"], optional=True,
                             depends=["enip_farm/server/_class1.h", "enip_farm/server/_receive.h"],
                             extra_compile_args=["-O2", "-Wall", "-Wextra"])])
