"""A real platform over a serial link: the frame codec (:mod:`~agents.serial.protocol`),
the host side (:class:`~agents.serial.platform.SerialPlatform`, flown by
:mod:`agents.gnc`; which device frames belong to its clock:
:mod:`~agents.serial.timeline`), an emulated device (:mod:`~agents.serial.emulator`, the simulated
plant behind the protocol) and its pseudo-terminal loop (:mod:`~agents.serial.pty`)
for rehearsals and tests.

Rule: as the rest of :mod:`agents`: imports only :mod:`federation.core`,
:mod:`schemas` and :mod:`agents`.
"""
