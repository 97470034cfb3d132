#!/usr/bin/env python3
"""Draws docs/firmware/wiring.svg (the pin map of firmware-protocol/avr/config.h) and renders
wiring.png with rsvg-convert: `python3 docs/firmware/wiring.py` (apt-get install librsvg2-bin)."""
import os, subprocess

W, H = 980, 560
parts = []
def box(x, y, w, h, title, fill):
    parts.append(f'<rect x="{x}" y="{y}" width="{w}" height="{h}" rx="8" fill="{fill}" stroke="#333" stroke-width="2"/>')
    parts.append(f'<text x="{x + w / 2}" y="{y + 22}" text-anchor="middle" font-weight="bold" font-size="16">{title}</text>')
def text(x, y, s, anchor="start", size=13):
    parts.append(f'<text x="{x}" y="{y}" text-anchor="{anchor}" font-size="{size}">{s}</text>')
def wire(x1, y1, x2, y2, color):
    parts.append(f'<polyline points="{x1},{y1} {(x1 + x2) / 2},{y1} {(x1 + x2) / 2},{y2} {x2},{y2}" fill="none" stroke="{color}" stroke-width="2.5"/>')

box(330, 40, 220, 440, "Arduino Uno / Nano", "#cfe3f5")
text(440, 78, "ATmega328P, 16 MHz", "middle", 12)
pins = [("D2", "table STEP", "#c0392b", "A", 0), ("D5", "table DIR", "#e67e22", "A", 1), ("D8", "ENABLE (low = on)", "#7f8c8d", "AB", 2),
        ("D3", "rail STEP", "#8e44ad", "B", 3), ("D6", "rail DIR", "#2980b9", "B", 4),
        ("D9", "index sensor (low = active)", "#16a085", "S1", 5), ("D10", "rail near-end switch (low)", "#27ae60", "S2", 6),
        ("A0", "E-STOP (low = pressed)", "#d35400", "E", 7), ("GND", "common ground", "#000", "G", 8)]
box(640, 40, 300, 130, "Driver 1: turntable (A4988 etc.)", "#f9e0d9")
text(650, 90, "STEP  DIR  EN  | VMOT 12 V, GND")
text(650, 110, "MS1-3: 1/16 microstepping")
text(650, 130, "motor: NEMA-17 200 steps, 4:1 belt")
text(650, 150, "= 12800 steps/rev (35.56 steps/degree)")
box(640, 200, 300, 110, "Driver 2: rail (optional)", "#e8dcf5")
text(650, 250, "STEP  DIR  EN | GT2 belt, 20T pulley")
text(650, 270, "1/16 microstepping: 80 steps/mm")
text(650, 290, "soft limits 0..400 mm (config.h)")
box(640, 340, 300, 90, "Sensors (to GND when active)", "#d9f2e6")
text(650, 385, "index: hall/optical on the table, 1 mark")
text(650, 405, "near-end: microswitch at rail position 0")
box(40, 340, 220, 90, "E-stop button", "#fde2c8")
text(50, 385, "between A0 and GND")
text(50, 405, "(internal pull-up; see docs)")
box(40, 40, 220, 130, "Host PC (cac)", "#eeeeee")
text(50, 90, "USB serial, 115200 8N1")
text(50, 110, "cac capture --port /dev/ttyACM0")
wire(260, 105, 330, 105, "#555")
text(265, 98, "USB", size=12)
for name, label, color, dest, i in pins:
    y = 100 + i * 40
    text(545, y + 4, name, "end", 14)
    text(340, y + 4, label, size=12)
    tx = {"A": (640, 100), "AB": (640, 120), "B": (640, 250), "S1": (640, 380), "S2": (640, 400), "E": (260, 385), "G": (640, 420)}[dest]
    if dest == "E":
        wire(330, y, tx[0], tx[1], color)
    else:
        wire(550, y, tx[0], tx[1] + (i % 2) * 6, color)
    if dest == "AB":
        wire(550, y, 640, 270, color)
text(W / 2, 530, "Pin map = Arduino CNC Shield V3 (X = turntable, Y = rail, X-/Y- end stops, Abort = E-stop): firmware-protocol/avr/config.h", "middle", 13)
svg = f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="DejaVu Sans, sans-serif"><rect width="100%" height="100%" fill="white"/>' + "".join(parts) + "</svg>"
here = os.path.dirname(os.path.abspath(__file__))
open(os.path.join(here, "wiring.svg"), "w").write(svg)
subprocess.run(["rsvg-convert", "-o", os.path.join(here, "wiring.png"), os.path.join(here, "wiring.svg")], check=True)
