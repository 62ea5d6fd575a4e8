"""Sentences written for this project (public domain, CC0), phonetically varied on purpose.

They mix bilabials (/p b m/: the lips must close), rounded vowels (/u o w/: anticipatory rounding),
open vowels (/a/: the jaw opens), labiodental and dental fricatives (/f v/, /th/), sibilants, and
questions and exclamations (prosody). Short (about 1.5-3 s at a normal rate) so the shipped sample stays small.
"""
from __future__ import annotations

SENTENCES: tuple[str, ...] = (
    "Bob bought a big blue boat.",
    "Maybe my mom made plum pie.",
    "Pam put the paper map back.",
    "Move the moon above the blue pool.",
    "Who knew you would choose blue shoes?",
    "Four fat frogs fell off the fence.",
    "Very few voices were heard.",
    "Think through the thick thorny path.",
    "She sells sea shells by the shore.",
    "Is the zoo open on Tuesday?",
    "Watch the white whale swim away.",
    "Father parked the car far away.",
    "I saw a hot dog at the park.",
    "Please open the window a little.",
    "Bring me the bottle of water.",
    "Where are you going so early?",
    "Ruby rode the red bike home.",
    "The cheerful child chose cheese.",
    "George judged the huge jump.",
    "Light the lamp in the hall.",
    "Nine new nurses needed a nap.",
    "Keep calm and carry on walking.",
    "Good food makes people happy.",
    "Why would anyone buy that?",
    "Oh no, the boat is sinking!",
    "Mary baked a dozen muffins.",
    "Bubbles pop when you blow on them.",
    "The old owl hooted at noon.",
    "Have you ever flown a plane?",
    "Wash your hands before lunch.",
    "The map shows a bumpy road.",
    "Paul plays the piano beautifully.",
    "A woman in a warm wool coat.",
    "Smooth music soothes the mood.",
    "The dog dug a deep hole.",
    "Fix the fan on the first floor.",
    "Put the book on the top shelf.",
    "My brother moved to Boston.",
    "Are we there yet?",
    "Amazing, we won the game!",
    "Ask Tom about the broken lamp.",
    "Quiet voices fill the room.",
    "Please remember to buy more milk.",
    "How much is the blue umbrella?",
    "We both waved goodbye at the bus.",
    "Those puppies play all morning.",
    "Open wide and say ah.",
    "Bake the bread at noon, Bob.",
)

assert len(SENTENCES) >= 40 and len(set(SENTENCES)) == len(SENTENCES)


def sentence_id(i: int) -> str:
    """Stable sentence id used in clip names: ``s00``, ``s01``, ..."""
    return f"s{i:02d}"
