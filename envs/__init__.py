"""The paper's car tasks as Gymnasium environments."""
