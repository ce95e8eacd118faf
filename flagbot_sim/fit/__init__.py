"""Fits and design searches on the steady solver and the sweep engines (issue #15).

    flagbot fit design1 data.csv --fit head.C1,head.C2,medium.mu --predict n3.csv
    flagbot optimize design1 --vary n=2:5,L=0.07:0.15,omega_rpm=20:250 --maximize v

Layout: ``data`` (DATA.csv: inputs, measured outputs, weights), ``evaluate`` (steady states of many scene
variants as engine tasks, continued along the motor speed), ``pool`` (the sweep engines kept open over many
batches), ``fit`` (weighted least squares, confidence intervals, identifiability, prediction), ``optimize``
(coarse grid + local refinement of a design space), ``plots``; the commands ``flagbot fit`` and ``optimize``
are :mod:`flagbot_sim.commands.fit`. See docs/usage.md "Fitting and design".
"""

