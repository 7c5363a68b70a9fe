"""A real platform over a serial link: the frame codec, the host side
(:class:`~agents.serial.platform.SerialPlatform`) and an emulated device behind a
pseudo-terminal for rehearsals and tests.

Rule: as the rest of :mod:`agents`: imports only :mod:`federation.core`,
:mod:`schemas` and :mod:`agents`.
"""
