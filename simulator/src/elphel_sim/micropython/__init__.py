"""Fake MicroPython ports (machine, time, network, socket, select) for unchanged firmware.

`esp8266.SimEsp8266` runs the files of ``target/esp8266`` in a thread against a virtual
clock and simulated pins; ``clock.VirtualClock`` models physical time so a simulated
move can run faster than real time; `links` holds the UART, sockets and poll, `modules`
the fake modules the firmware imports.
"""
