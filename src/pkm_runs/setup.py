from setuptools import setup

package_name = 'pkm_runs'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'Reading a recorded run: its data in memory and as frames, the report with its metrics and plots, the bit-exact replay.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pkm-report = pkm_runs.report:main',
            'pkm-replay = pkm_runs.replay:main',
        ],
    },
)
