"""Place recognition: a bag-of-binary-words vocabulary (DBoW2 idea) for loop closing and peers."""
from canopy.place.vocabulary import Vocabulary

__all__ = ["Vocabulary"]
