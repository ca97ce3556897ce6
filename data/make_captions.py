#!/usr/bin/env python3
"""Generate data/captions.txt: the negative-caption pool of `t2tf optimize`.

The paper samples negatives from LAION captions, which cannot ship. This script writes the
project's own pool instead: short, varied, everyday image captions built from the word lists and
templates below (all written for this project), drawn with a seeded RNG so the file is
reproducible. Output: one caption per line, deduplicated, lower case, in generation order.

    python3 data/make_captions.py            # writes data/captions.txt beside this script
    python3 data/make_captions.py --count 8000 --seed 7 --out other.txt
"""
import argparse
import os
import random

PEOPLE = [
    "a man", "a woman", "a boy", "a girl", "an old man", "an old woman", "a child", "a baby",
    "two children", "a young couple", "a group of friends", "a family", "a chef", "a farmer",
    "a surfer", "a skateboarder", "a cyclist", "a runner", "a musician", "a street vendor",
    "a teacher", "a nurse", "a firefighter", "a police officer", "a fisherman", "a painter",
    "a tourist", "a student", "a soccer player", "a tennis player", "a bride", "a groom",
    "a construction worker", "a waiter", "a hiker", "a climber", "a dancer", "a photographer",
]
ANIMALS = [
    "a dog", "a puppy", "a cat", "a kitten", "a horse", "a cow", "a sheep", "a goat", "a pig",
    "a chicken", "a duck", "a swan", "a pigeon", "a parrot", "an owl", "an eagle", "a seagull",
    "a squirrel", "a rabbit", "a deer", "a fox", "a bear", "an elephant", "a giraffe", "a zebra",
    "a lion", "a tiger", "a monkey", "a turtle", "a frog", "a lizard", "a butterfly", "a bee",
    "a goldfish", "a dolphin", "a whale", "a crab", "a snail", "a hedgehog", "a camel",
]
OBJECTS = [
    "a red bicycle", "a blue car", "a yellow taxi", "a city bus", "a train", "a sailboat",
    "a fishing boat", "an airplane", "a motorcycle", "a pickup truck", "a tractor", "a scooter",
    "a wooden chair", "a leather sofa", "a kitchen table", "a desk lamp", "a bookshelf",
    "a stack of books", "an open laptop", "a smartphone", "a coffee mug", "a teapot",
    "a glass of water", "a bottle of wine", "a vase of flowers", "a potted plant",
    "a wall clock", "an umbrella", "a backpack", "a pair of shoes", "a straw hat",
    "a guitar", "a piano", "a violin", "a soccer ball", "a tennis racket", "a kite",
    "a teddy bear", "a toy robot", "a birthday cake", "a pizza", "a bowl of soup",
    "a plate of pasta", "a sandwich", "a basket of apples", "a loaf of bread", "a cup of coffee",
    "a bowl of fruit", "a hamburger", "a stack of pancakes", "a bunch of bananas",
    "a red mailbox", "a street sign", "a traffic light", "a fire hydrant", "a park bench",
    "a wooden fence", "a stone bridge", "a lighthouse", "a windmill", "a tent", "a campfire",
    "a snowman", "a sandcastle", "a hot air balloon", "a ferris wheel", "a bicycle rack",
]
PLACES = [
    "on a beach", "in a park", "in a kitchen", "in a living room", "on a city street",
    "in a forest", "on a mountain trail", "by a lake", "near a river", "in a garden",
    "on a farm", "in a classroom", "in an office", "at a train station", "at an airport",
    "in a supermarket", "at a market", "in a cafe", "in a restaurant", "on a bridge",
    "in the snow", "in the rain", "in a field of flowers", "in the desert", "at the zoo",
    "on a boat", "in a backyard", "on a rooftop", "in a library", "in a museum",
    "at a playground", "on a balcony", "in a parking lot", "under a tree", "on a dirt road",
    "next to a window", "in front of a house", "on a wooden table", "on the grass",
    "at a bus stop", "in a stadium", "on a frozen pond", "in a small village", "at the harbor",
]
PERSON_ACTIONS = [
    "riding a bike", "walking a dog", "reading a book", "drinking coffee", "eating lunch",
    "cooking dinner", "playing the guitar", "taking a photo", "talking on the phone",
    "carrying a bag", "holding an umbrella", "flying a kite", "playing soccer", "sitting on a bench",
    "waiting for a bus", "painting a wall", "typing on a laptop", "smiling at the camera",
    "laughing together", "jumping in the air", "sleeping on a couch", "watering plants",
    "buying vegetables", "throwing a frisbee", "swimming", "skiing down a slope", "running",
    "climbing a rock", "dancing", "looking at a map", "pushing a stroller", "feeding ducks",
    "washing dishes", "building a sandcastle", "riding a horse", "playing chess",
]
ANIMAL_ACTIONS = [
    "sleeping", "running", "sitting", "eating", "playing with a ball", "lying in the sun",
    "looking at the camera", "drinking water", "jumping", "swimming", "standing still",
    "chasing a ball", "resting", "walking slowly", "hiding in the grass", "climbing a tree",
]
ADJ = [
    "small", "large", "old", "new", "bright", "dark", "colorful", "quiet", "busy", "empty",
    "crowded", "sunny", "foggy", "snowy", "wet", "dusty", "clean", "messy", "cozy", "modern",
]
SCENES = [
    "street", "kitchen", "room", "beach", "park", "market", "harbor", "village", "garden",
    "road", "bridge", "station", "office", "field", "forest", "lake", "city square", "alley",
    "playground", "bakery", "bookstore", "classroom", "farmhouse", "parking lot", "hallway",
]
TIMES = [
    "at sunset", "at sunrise", "at night", "in the morning", "in the afternoon", "in winter",
    "in summer", "in autumn", "in spring", "on a cloudy day", "after the rain", "at dusk",
]
STYLES = [
    "a photo of", "a close-up photo of", "a black and white photo of", "a blurry photo of",
    "a picture of", "an old photo of", "a painting of", "a drawing of", "a cartoon of",
    "a watercolor of", "a sketch of", "a poster of", "an aerial view of", "a postcard of",
]
COLORS = [
    "red", "blue", "green", "yellow", "orange", "purple", "pink", "white", "black", "brown",
    "gray", "golden",
]
THINGS = [
    "flowers", "balloons", "apples", "leaves", "umbrellas", "boats", "cars", "houses",
    "chairs", "bottles", "candles", "shoes", "books", "pencils", "cups", "plates", "tiles",
    "bricks", "doors", "windows", "kites", "lanterns", "shells", "stones",
]
COUNTS = ["two", "three", "four", "five", "a few", "many", "a row of", "a pile of"]


def strip_article(s):
    for a in ("a ", "an "):
        if s.startswith(a):
            return s[len(a):]
    return s


def article(word):
    return ("an " if word[0] in "aeiou" else "a ") + word


TEMPLATES = [
    lambda r: f"{r.choice(PEOPLE)} {r.choice(PERSON_ACTIONS)} {r.choice(PLACES)}",
    lambda r: f"{r.choice(PEOPLE)} {r.choice(PERSON_ACTIONS)}",
    lambda r: f"{r.choice(ANIMALS)} {r.choice(ANIMAL_ACTIONS)} {r.choice(PLACES)}",
    lambda r: f"{r.choice(ANIMALS)} {r.choice(ANIMAL_ACTIONS)}",
    lambda r: f"{r.choice(OBJECTS)} {r.choice(PLACES)}",
    lambda r: f"{r.choice(STYLES)} {r.choice(OBJECTS)}",
    lambda r: f"{r.choice(STYLES)} {r.choice(ANIMALS)}",
    lambda r: f"{r.choice(STYLES)} {r.choice(PEOPLE)}",
    lambda r: f"{article(r.choice(ADJ))} {r.choice(SCENES)} {r.choice(TIMES)}",
    lambda r: f"{r.choice(STYLES)} {article(r.choice(ADJ))} {r.choice(SCENES)}",
    lambda r: f"{r.choice(COUNTS)} {r.choice(COLORS)} {r.choice(THINGS)}",
    lambda r: f"{r.choice(COUNTS)} {r.choice(COLORS)} {r.choice(THINGS)} {r.choice(PLACES)}",
    lambda r: f"{r.choice(ANIMALS)} next to {r.choice(OBJECTS)}",
    lambda r: f"{r.choice(PEOPLE)} with {r.choice(ANIMALS)} {r.choice(PLACES)}",
    lambda r: f"{r.choice(OBJECTS)} {r.choice(TIMES)}",
    lambda r: f"{article(r.choice(COLORS))} {strip_article(r.choice(OBJECTS))}",
    lambda r: f"the view from {r.choice(['a window', 'a hill', 'a tower', 'a train', 'a car', 'a plane'])} {r.choice(TIMES)}",
    lambda r: "{} and {} {}".format(*r.sample(PEOPLE, 2), r.choice(PLACES)),
]


def generate(count, seed):
    rng = random.Random(seed)
    seen = set()
    out = []
    tries = 0
    while len(out) < count:
        tries += 1
        if tries > count * 100:
            raise SystemExit(f"only {len(out)} distinct captions after {tries} draws")
        c = rng.choice(TEMPLATES)(rng).strip().lower()
        if c not in seen:
            seen.add(c)
            out.append(c)
    return out


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=6000)
    p.add_argument("--seed", type=int, default=20261123)
    p.add_argument("--out", default=os.path.join(here, "captions.txt"))
    a = p.parse_args()
    caps = generate(a.count, a.seed)
    tmp = a.out + ".partial"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write("\n".join(caps) + "\n")
    os.replace(tmp, a.out)
    print(f"wrote {len(caps)} captions to {a.out}")


if __name__ == "__main__":
    main()
