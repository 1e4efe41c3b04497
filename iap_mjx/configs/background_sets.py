"""The background sets of the Distracting Control Suite, as data: the reference's DAVIS-2017
training and validation video lists, and the photographs shipped in scikit-image and matplotlib
that stand in for them offline (sources and licences in ``docs/backgrounds.md``).

:mod:`iap_mjx.configs.distraction` checks a background setting against these lists;
:mod:`iap_mjx.envs.backgrounds` reads the pixels.
"""

from __future__ import annotations

import dataclasses

# distracting_control/background.py: DAVIS17_TRAINING_VIDEOS, in the reference's order
# (a level uses the first N).
DAVIS17_TRAINING_VIDEOS = (
    "bear",
    "bmx-bumps",
    "boat",
    "boxing-fisheye",
    "breakdance-flare",
    "bus",
    "car-turn",
    "cat-girl",
    "classic-car",
    "color-run",
    "crossing",
    "dance-jump",
    "dancing",
    "disc-jockey",
    "dog-agility",
    "dog-gooses",
    "dogs-scale",
    "drift-turn",
    "drone",
    "elephant",
    "flamingo",
    "hike",
    "hockey",
    "horsejump-low",
    "kid-football",
    "kite-walk",
    "koala",
    "lady-running",
    "lindy-hop",
    "longboard",
    "lucia",
    "mallard-fly",
    "mallard-water",
    "miami-surf",
    "motocross-bumps",
    "motorbike",
    "night-race",
    "paragliding",
    "planes-water",
    "rallye",
    "rhino",
    "rollerblade",
    "schoolgirls",
    "scooter-board",
    "scooter-gray",
    "sheep",
    "skate-park",
    "snowboard",
    "soccerball",
    "stroller",
    "stunt",
    "surf",
    "swing",
    "tennis",
    "tractor-sand",
    "train",
    "tuk-tuk",
    "upside-down",
    "varanus-cage",
    "walking",
)
# distracting_control/background.py: DAVIS17_VALIDATION_VIDEOS, in the reference's order
# (``background_dataset_videos="val"``).
DAVIS17_VALIDATION_VIDEOS = (
    "bike-packing",
    "blackswan",
    "bmx-trees",
    "breakdance",
    "camel",
    "car-roundabout",
    "car-shadow",
    "cows",
    "dance-twirl",
    "dog",
    "dogs-jump",
    "drift-chicane",
    "drift-straight",
    "goat",
    "gold-fish",
    "horsejump-high",
    "india",
    "judo",
    "kite-surf",
    "lab-coat",
    "libby",
    "loading",
    "mbike-trick",
    "motocross-jump",
    "paragliding-launch",
    "parkour",
    "pigs",
    "scooter-black",
    "shooting",
    "soapbox",
)


@dataclasses.dataclass(frozen=True)
class Photograph:
    """One photograph shipped in an installed package, and the pan/zoom path made from it.

    Attributes:
      name: the video's name (the package's name for the image).
      filename: the file inside the package's data directory (``PACKAGE_DATA``).
      source: who made it, where from (as the package's documentation states it).
      licence: its licence, as the package's documentation states it.
      zoom: ``(min, max)``: the window's side is ``min(H, W) / zoom``.
      pan: how far the window's centre moves, a fraction of the room the window leaves.
      package: ``"skimage"`` or ``"matplotlib"``.
    """

    name: str
    filename: str
    source: str
    licence: str
    zoom: tuple[float, float] = (1.25, 1.6)
    pan: float = 0.9
    package: str = "skimage"


# Where each package keeps its sample images.
PACKAGE_DATA = {"skimage": ("data",), "matplotlib": ("mpl-data", "sample_data")}


# Colour photographs first, so that easy and medium draw from them; all ten ship in the
# scikit-image 0.26.0 wheel (listed in its RECORD), none is fetched on demand.
PHOTOGRAPHS = (
    Photograph("astronaut", "astronaut.png", "Eileen Collins, NASA Great Images database", "public domain (NASA)"),
    Photograph("coffee", "coffee.png", "coffee cup, Rachel Michetti, courtesy of Pikolo Espresso Bar", "CC0"),
    Photograph("chelsea", "chelsea.png", "Chelsea the cat, Stefan van der Walt", "CC0"),
    Photograph(
        "rocket", "rocket.jpg", "DSCOVR launch on Falcon 9, SpaceX Photos", "public domain (released by SpaceX)"
    ),
    Photograph(
        "hubble_deep_field",
        "hubble_deep_field.jpg",
        "Hubble eXtreme Deep Field, NASA/HubbleSite",
        "public domain (NASA)",
    ),
    # A fundus photograph is a bright disc on black: stay near its centre.
    Photograph(
        "retina",
        "retina.jpg",
        "fundus photograph, Mikael Haggstrom, Wikimedia Commons",
        "CC0",
        zoom=(2.0, 2.5),
        pan=0.3,
    ),
    Photograph("camera", "camera.png", "photographer with a camera, Lav Varshney (greyscale)", "CC0"),
    Photograph("brick", "brick.png", "brick wall, CC0Textures Bricks25 (greyscale)", "CC0"),
    Photograph("grass", "grass.png", "grass, linolafett on DeviantArt (greyscale)", "CC0"),
    Photograph("gravel", "gravel.png", "gravel, CC0Textures Gravel04 (greyscale)", "CC0"),
)

# Held out: none of these is in PHOTOGRAPHS. Colour first, as above; the set has fewer colour
# photographs (3 of 10, against 6), so it also moves the colour statistics away from training.
VALIDATION_PHOTOGRAPHS = (
    Photograph(
        "motorcycle_left",
        "motorcycle_left.png",
        "Middlebury 2014 stereo benchmark (Nesic, Westling, Wang, Kitajima, Krathwohl, Scharstein), left view",
        "not stated by scikit-image (Middlebury's research data)",
    ),
    Photograph(
        "immunohistochemistry",
        "ihc.png",
        "colonic glands, IHC staining, Center for Microscopy And Molecular Imaging",
        "no known copyright restrictions",
    ),
    Photograph(
        "grace_hopper",
        "grace_hopper.jpg",
        "Rear Admiral Grace Hopper, U.S. Navy photograph",
        "public domain (U.S. Navy)",
        package="matplotlib",
    ),
    Photograph(
        "coins", "coins.png", "Greek coins from Pompeii, Brooklyn Museum (greyscale)", "no known copyright restrictions"
    ),
    Photograph(
        "clock", "clock_motion.png", "motion-blurred wall clock, Stefan van der Walt (greyscale)", "public domain"
    ),
    Photograph("cell", "cell.png", "cell in saline, quantitative phase image, Paul Mueller (greyscale)", "CC0"),
    Photograph("text", "text.png", "text for corner detection, Wikipedia File:Corner.png (greyscale)", "public domain"),
    Photograph("moon", "moon.png", "surface of the moon (greyscale)", "not stated by scikit-image"),
    Photograph("page", "page.png", "scanned page of printed text (greyscale)", "not stated by scikit-image"),
    Photograph(
        "microaneurysms",
        "microaneurysms.png",
        "retina detail, HRF fundus image database, Andreas Maier (greyscale)",
        "CC0",
        zoom=(1.1, 1.3),
        pan=0.5,
    ),
)
