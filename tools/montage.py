#!/usr/bin/env python3
"""Side-by-side montage of `lfr compare` images for the docs (needs Pillow: pip install pillow).

    python3 tools/montage.py OUT.png COMPARE_DIR LABEL=STEM [LABEL=STEM ...] [--crop X,Y,W,H] [--scale S]

STEM names an image of COMPARE_DIR/images without extension (e.g. `gif-1spp`, `reference`,
`gif-1spp-error`). Each tile is cropped, scaled by nearest neighbour and labelled below. A doc
tool only: nothing in the build or the tests needs it.
"""

import sys
from pathlib import Path

from PIL import Image, ImageDraw


def main(argv):
    crop, scale, tiles, rows = None, 1, [], 1
    args = list(argv[1:])
    while "--crop" in args or "--scale" in args or "--rows" in args:
        for flag in ("--crop", "--scale", "--rows"):
            if flag in args:
                i = args.index(flag)
                value = args[i + 1]
                del args[i : i + 2]
                if flag == "--crop":
                    crop = tuple(int(v) for v in value.split(","))
                elif flag == "--scale":
                    scale = int(value)
                else:
                    rows = int(value)
    if len(args) < 3:
        sys.exit(__doc__)
    out, compare_dir = Path(args[0]), Path(args[1])
    for spec in args[2:]:
        label, stem = spec.split("=", 1)
        image = Image.open(compare_dir / "images" / f"{stem}.png").convert("RGB")
        if crop:
            x, y, w, h = crop
            image = image.crop((x, y, x + w, y + h))
        image = image.resize((image.width * scale, image.height * scale), Image.NEAREST)
        tiles.append((label, image))
    label_height = 18
    tile_w = max(t.width for _, t in tiles)
    tile_h = max(t.height for _, t in tiles) + label_height
    columns = (len(tiles) + rows - 1) // rows
    sheet = Image.new("RGB", (columns * (tile_w + 4) + 4, rows * (tile_h + 4) + 4), "white")
    draw = ImageDraw.Draw(sheet)
    for k, (label, tile) in enumerate(tiles):
        x = 4 + (k % columns) * (tile_w + 4)
        y = 4 + (k // columns) * (tile_h + 4)
        sheet.paste(tile, (x, y))
        draw.text((x + 2, y + tile.height + 3), label, fill="black")
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out, quality=90) if out.suffix.lower() in (".jpg", ".jpeg") else sheet.save(out, optimize=True)
    print(f"wrote {out} ({sheet.width}x{sheet.height})")


if __name__ == "__main__":
    main(sys.argv)
